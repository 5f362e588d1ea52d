#include "common/check.h"

#include <cstdio>
#include <cstdlib>
#include <stdexcept>

namespace kinevis::common::internal {

void Abort(const char* condition, const char* file, int line) {
  std::fprintf(stderr, "kinevis: internal error (a bug): %s:%d: %s failed\n", file, line,
               condition);
  std::fflush(stderr);
  std::abort();
}

void Abort(const char* condition, const std::string& message, const char* file, int line) {
  std::fprintf(stderr, "kinevis: internal error (a bug): %s:%d: %s failed: %s\n", file, line,
               condition, message.c_str());
  std::fflush(stderr);
  std::abort();
}

void ThrowInvalidArgument(const std::string& message, const char* condition, const char* file,
                          int line) {
  throw std::invalid_argument(message + " (" + condition + " failed at " + file + ":" +
                              std::to_string(line) + ")");
}

}  // namespace kinevis::common::internal
