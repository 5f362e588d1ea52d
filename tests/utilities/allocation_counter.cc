#include "tests/utilities/allocation_counter.h"

#include <cstdlib>
#include <new>

namespace kinevis::testing {
namespace {

thread_local long t_allocations = 0;
thread_local bool t_counting = true;

void* CountedAlloc(std::size_t size) {
  if (t_counting) ++t_allocations;
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}

}  // namespace

long ThreadAllocations() { return t_allocations; }

UncountedAllocations::UncountedAllocations() : saved_(t_counting) { t_counting = false; }
UncountedAllocations::~UncountedAllocations() { t_counting = saved_; }

}  // namespace kinevis::testing

void* operator new(std::size_t size) { return kinevis::testing::CountedAlloc(size); }
void* operator new[](std::size_t size) { return kinevis::testing::CountedAlloc(size); }
// GCC cannot see that every pointer reaching these came from the malloc() above.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop
