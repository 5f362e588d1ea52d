#pragma once

// For the result-file tests: turns a version 2 result file (written by the code under test) into
// the version 1 file of the same content, as written before the estimator contract: the
// trailing `estimation:` block is cut and `version: 2` becomes `version: 1`.

#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>

namespace kinevis::testing {

// Rewrites `path` in place; throws std::runtime_error when it holds no estimation block or no
// `version: 2` (so a test cannot pass by reading the new file back unchanged).
inline void RewriteAsVersionOne(const std::string& path) {
  std::string text;
  {
    std::ifstream in(path);
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const size_t block = text.find("\nestimation:");
  const size_t version = text.find("version: 2");
  if (block == std::string::npos || version == std::string::npos) {
    throw std::runtime_error(path + ": no estimation block or no version 2 to rewrite");
  }
  text.erase(block + 1);
  text.replace(version, 10, "version: 1");
  std::ofstream(path) << text;
}

}  // namespace kinevis::testing
