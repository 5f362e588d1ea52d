#pragma once

// Proving "no allocation in the cycle": linking kinevis_test_allocation_counter replaces the
// global operator new/delete of the test program with versions that count, per thread, every
// allocation the calling thread makes. Measure a difference:
//
//   const long before = ThreadAllocations();
//   ...code under test...
//   EXPECT_EQ(ThreadAllocations() - before, 0);
//
// Allocations of other threads (simulators, servers) are not counted; work on this thread that
// is not the code under test can be excluded with an UncountedAllocations scope.

namespace kinevis::testing {

// Allocations (operator new and new[]) made so far by the calling thread, outside
// UncountedAllocations scopes.
long ThreadAllocations();

class UncountedAllocations {
 public:
  UncountedAllocations();
  ~UncountedAllocations();
  UncountedAllocations(const UncountedAllocations&) = delete;
  UncountedAllocations& operator=(const UncountedAllocations&) = delete;

 private:
  bool saved_;
};

}  // namespace kinevis::testing
