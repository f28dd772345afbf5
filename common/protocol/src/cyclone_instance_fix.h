#pragma once
// See cyclone_instance_fix.c.
#include <dds/dds.h>

#ifdef __cplusplus
extern "C" {
#endif

/// After a writer whose history indexed `instance` (a transient-local writer that wrote it)
/// unregistered it: drops the reference Cyclone DDS 0.10 forgets to. Returns 1 if it did.
/// Call on the thread that unregistered, right after.
int telehand_dds_release_unregistered(dds_instance_handle_t instance);

/// Frees the samples Cyclone DDS 0.10 keeps on its pool for reuse (a no-op with other
/// versions), in the domain this thread last called into. Returns how many it freed. Safe
/// while other threads write and receive: the pool is taken under its own locks.
int telehand_dds_release_pooled_samples(void);

#ifdef __cplusplus
}
#endif
