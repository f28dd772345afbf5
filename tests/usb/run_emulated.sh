#!/bin/sh
# Runs a test program under umockdev's preload library (the emulated USB bus). ASan's
# link-order check trips over the preload library (docs/facts.md "umockdev"): it is turned off,
# other ASAN_OPTIONS are kept.
export ASAN_OPTIONS="verify_asan_link_order=0${ASAN_OPTIONS:+:$ASAN_OPTIONS}"
exec umockdev-wrapper "$@"
