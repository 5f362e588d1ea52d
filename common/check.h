#pragma once

// The check macros of the first two error tiers (STYLE.md; Drake's DRAKE_DEMAND and
// DRAKE_THROW_UNLESS are the model):
//
//  - KINEVIS_DEMAND(condition): a broken invariant, i.e. a bug in kinevis. Always on, in every
//    build type (unlike assert, which RelWithDebInfo compiles out): prints the condition with file
//    and line to stderr and aborts. Use it where going on would corrupt memory or give a silent
//    wrong answer, e.g. the bound checked before a copy into a fixed-size frame.
//    KINEVIS_DEMAND_MSG(condition, message) adds a message; KINEVIS_UNREACHABLE() marks a path
//    that no valid state reaches.
//
//  - KINEVIS_THROW_UNLESS(condition, message): bad input from the caller of a library function.
//    Throws std::invalid_argument with `message` (a std::string expression, evaluated only when
//    the check fails, so it may format the offending values), the condition, and file:line.
//    Bad *configuration* (a file, a command line) is collected with common::Problems instead
//    (common/config_error.h), so that every bad field is reported at once.
//
// Expected faults at run time (the third tier: timeouts, CRC errors, drive faults) are neither:
// they are status values, never checks.

#include <string>

namespace kinevis::common::internal {

[[noreturn]] void Abort(const char* condition, const char* file, int line);
[[noreturn]] void Abort(const char* condition, const std::string& message, const char* file,
                        int line);
[[noreturn]] void ThrowInvalidArgument(const std::string& message, const char* condition,
                                       const char* file, int line);

}  // namespace kinevis::common::internal

#define KINEVIS_DEMAND(condition)                                         \
  do {                                                                    \
    if (!(condition)) {                                                   \
      ::kinevis::common::internal::Abort(#condition, __FILE__, __LINE__); \
    }                                                                     \
  } while (false)

// As KINEVIS_DEMAND, with a message (a std::string expression, evaluated only on failure) that
// says which object broke the invariant.
#define KINEVIS_DEMAND_MSG(condition, message)                                       \
  do {                                                                               \
    if (!(condition)) {                                                              \
      ::kinevis::common::internal::Abort(#condition, (message), __FILE__, __LINE__); \
    }                                                                                \
  } while (false)

#define KINEVIS_UNREACHABLE() ::kinevis::common::internal::Abort("unreachable", __FILE__, __LINE__)

#define KINEVIS_THROW_UNLESS(condition, message)                                         \
  do {                                                                                   \
    if (!(condition)) {                                                                  \
      ::kinevis::common::internal::ThrowInvalidArgument((message), #condition, __FILE__, \
                                                        __LINE__);                       \
    }                                                                                    \
  } while (false)
