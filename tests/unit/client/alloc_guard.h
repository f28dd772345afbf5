#pragma once
// Counting replacements of the global operator new/delete, armed per thread, and a guard
// that counts the heap traffic of the current thread while in scope. Defines the global
// operators: include it in exactly one source file of a test executable.
#include <algorithm>
#include <cstdlib>
#include <new>

namespace {

thread_local bool t_armed = false;
thread_local std::size_t t_allocations = 0;
thread_local std::size_t t_deallocations = 0;

void* allocate(std::size_t n) noexcept {
  if (t_armed) ++t_allocations;
  return std::malloc(n == 0 ? 1 : n);
}

void* allocateAligned(std::size_t n, std::align_val_t al) noexcept {
  if (t_armed) ++t_allocations;
  void* p = nullptr;
  const std::size_t a = std::max(static_cast<std::size_t>(al), sizeof(void*));
  return posix_memalign(&p, a, n == 0 ? 1 : n) == 0 ? p : nullptr;
}

void* allocateOrThrow(std::size_t n) {
  if (void* p = allocate(n)) return p;
  throw std::bad_alloc();
}

void* allocateAlignedOrThrow(std::size_t n, std::align_val_t al) {
  if (void* p = allocateAligned(n, al)) return p;
  throw std::bad_alloc();
}

void release(void* p) noexcept {
  if (p == nullptr) return;
  if (t_armed) ++t_deallocations;
  std::free(p);
}

}  // namespace

// NOLINTBEGIN(misc-new-delete-overloads): every replaceable form, counted.
void* operator new(std::size_t n) { return allocateOrThrow(n); }
void* operator new[](std::size_t n) { return allocateOrThrow(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept { return allocate(n); }
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept { return allocate(n); }
void* operator new(std::size_t n, std::align_val_t al) { return allocateAlignedOrThrow(n, al); }
void* operator new[](std::size_t n, std::align_val_t al) { return allocateAlignedOrThrow(n, al); }
void* operator new(std::size_t n, std::align_val_t al, const std::nothrow_t&) noexcept {
  return allocateAligned(n, al);
}
void* operator new[](std::size_t n, std::align_val_t al, const std::nothrow_t&) noexcept {
  return allocateAligned(n, al);
}
void operator delete(void* p) noexcept { release(p); }
void operator delete[](void* p) noexcept { release(p); }
void operator delete(void* p, std::size_t) noexcept { release(p); }
void operator delete[](void* p, std::size_t) noexcept { release(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { release(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { release(p); }
void operator delete(void* p, std::align_val_t) noexcept { release(p); }
void operator delete[](void* p, std::align_val_t) noexcept { release(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { release(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { release(p); }
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept { release(p); }
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept { release(p); }
// NOLINTEND(misc-new-delete-overloads)

namespace telehand::test {

/// Counts heap traffic on this thread while in scope.
class AllocationGuard {
 public:
  AllocationGuard() : a0_(t_allocations), d0_(t_deallocations) { t_armed = true; }
  ~AllocationGuard() { t_armed = false; }
  AllocationGuard(const AllocationGuard&) = delete;
  AllocationGuard& operator=(const AllocationGuard&) = delete;
  std::size_t allocations() const { return t_allocations - a0_; }
  std::size_t deallocations() const { return t_deallocations - d0_; }

 private:
  std::size_t a0_, d0_;
};

/// Keeps the optimizer from eliding an allocation whose result is otherwise unused.
void escape(const void* p) { asm volatile("" : : "g"(p) : "memory"); }

}  // namespace telehand::test
