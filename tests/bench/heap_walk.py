#!/usr/bin/env python3
"""What holds a process's main malloc arena resident (docs/security.md "Memory").

Walks glibc's chunks in the [heap] mapping of a running process (read from /proc/PID/mem,
so root or the process's owner with ptrace rights), and prints the blocks in use grouped by
size and by what their first two words point into (a heap pointer, a library, or neither:
list nodes begin with two heap pointers, C++ objects with a vtable in their binary), the
pages they sit on, and the largest blocks. Blocks in glibc's per-thread cache look in use.

Usage: tests/bench/heap_walk.py PID [--top N]
"""
import argparse
import bisect
import collections
import struct
import sys


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pid", type=int, help="the process to walk")
    ap.add_argument("--top", type=int, default=30, help="groups and largest blocks to print")
    args = ap.parse_args()
    try:
        maps = []
        with open(f"/proc/{args.pid}/maps") as f:
            for line in f:
                parts = line.split()
                lo, hi = (int(x, 16) for x in parts[0].split("-"))
                maps.append((lo, hi, parts[5] if len(parts) > 5 else ""))
        heaps = [m for m in maps if m[2] == "[heap]"]
        if not heaps:
            sys.exit(f"heap_walk: process {args.pid} has no [heap] mapping")
        lo, hi, _ = heaps[0]
        with open(f"/proc/{args.pid}/mem", "rb") as mem:
            mem.seek(lo)
            data = mem.read(hi - lo)
    except OSError as e:
        sys.exit(f"heap_walk: cannot read process {args.pid}: {e}")

    starts = [m[0] for m in maps]

    def owner(p):
        i = bisect.bisect_right(starts, p) - 1
        if i >= 0 and maps[i][0] <= p < maps[i][1]:
            return maps[i][2].split("/")[-1] or "anonymous"
        return "-"

    chunks, off = [], 0
    while off + 16 <= len(data):
        size = struct.unpack_from("<Q", data, off + 8)[0] & ~7
        if size < 32 or off + size > len(data):
            break
        chunks.append((off, size))
        off += size
    used = [c for i, c in enumerate(chunks[:-1])
            if struct.unpack_from("<Q", data, chunks[i + 1][0] + 8)[0] & 1]
    pages = set()
    groups, group_bytes = collections.Counter(), collections.Counter()
    for o, size in used:
        w0, w1 = struct.unpack_from("<QQ", data, o + 16)
        key = (size, owner(w0), owner(w1))
        groups[key] += 1
        group_bytes[key] += size
        pages.update(range((lo + o) // 4096, (lo + o + size - 1) // 4096 + 1))
    print(f"[heap] {(hi - lo) / 2**20:.1f} MB: {len(chunks)} chunks walked, "
          f"{len(used)} in use ({sum(s for _, s in used) / 2**20:.2f} MB) "
          f"on {len(pages)} pages ({len(pages) * 4096 / 2**20:.1f} MB)")
    print("blocks  bytes  (chunk size, first word into, second word into)")
    for key, n in groups.most_common(args.top):
        print(f"{n:6d} {group_bytes[key]:8d}  {key}")
    print("largest:", ", ".join(f"{s} B" for _, s in sorted(used, key=lambda c: -c[1])[:args.top]))


if __name__ == "__main__":
    main()
