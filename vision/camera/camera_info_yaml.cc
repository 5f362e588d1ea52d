#include "vision/camera/camera_info_yaml.h"

#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <opencv2/core.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

namespace kinevis::vision {
namespace {

const char* const kRosKeys[] = {"image_width",          "image_height",
                                "camera_name",          "camera_matrix",
                                "distortion_model",     "distortion_coefficients",
                                "rectification_matrix", "projection_matrix"};

// Shortest decimal text that reads back to the same double (C++17 to_chars).
std::string Number(double value) {
  char buffer[64];
  const std::to_chars_result r = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, r.ptr);
}

std::string Quoted(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        out += c;
    }
  }
  return out + "\"";
}

void WriteMatrix(std::ostream& out, const char* key, int rows, int cols, const double* data) {
  out << key << ":\n  rows: " << rows << "\n  cols: " << cols << "\n  data: [";
  for (int i = 0; i < rows * cols; ++i) out << (i ? ", " : "") << Number(data[i]);
  out << "]\n";
}

bool IsIdentifier(const std::string& key) {
  if (key.empty() || !(std::isalpha(static_cast<unsigned char>(key[0])) || key[0] == '_')) {
    return false;
  }
  for (char c : key) {
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) return false;
  }
  return true;
}

std::string CheckParameters(const PinholeBrownParameters& p) {
  std::ostringstream e;
  if (p.width <= 0) e << "width = " << p.width << " must be > 0; ";
  if (p.height <= 0) e << "height = " << p.height << " must be > 0; ";
  if (!std::isfinite(p.fx) || p.fx <= 0) e << "fx = " << p.fx << " must be finite and > 0; ";
  if (!std::isfinite(p.fy) || p.fy <= 0) e << "fy = " << p.fy << " must be finite and > 0; ";
  if (!std::isfinite(p.cx)) e << "cx = " << p.cx << " is not finite; ";
  if (!std::isfinite(p.cy)) e << "cy = " << p.cy << " is not finite; ";
  for (int i = 0; i < 8; ++i) {
    if (!std::isfinite(p.distortion[i])) {
      e << "distortion[" << i << "] = " << p.distortion[i] << " is not finite; ";
    }
  }
  return e.str();
}

// OpenCV's YAML reader (4.x) needs a %YAML directive, which ROS files lack, and fails on a plain
// scalar that starts with a digit (ROS writes camera serial numbers such as 00b09d0100990bb6
// unquoted as camera_name). Both are fixed on the text before parsing; everything else is
// parsed as written. Returns the number of lines added in front (for error messages).
int PrepareForOpenCv(std::string* text) {
  // Quote an unquoted top-level camera_name value.
  size_t pos = 0;
  while (pos < text->size()) {
    size_t end = text->find('\n', pos);
    if (end == std::string::npos) end = text->size();
    const std::string line = text->substr(pos, end - pos);
    static const char kKey[] = "camera_name:";
    if (line.compare(0, std::strlen(kKey), kKey) == 0) {
      std::string value = line.substr(std::strlen(kKey));
      const size_t first = value.find_first_not_of(" \t");
      const size_t last = value.find_last_not_of(" \t\r");
      if (first != std::string::npos) {
        value = value.substr(first, last - first + 1);
        if (value[0] != '"' && value[0] != '\'' && value.find('#') == std::string::npos) {
          text->replace(pos, end - pos, std::string(kKey) + " " + Quoted(value));
        }
      }
      break;
    }
    pos = end + 1;
  }
  if (text->compare(0, 5, "%YAML") == 0) return 0;
  if (text->compare(0, 3, "---") == 0) {
    text->insert(0, "%YAML:1.0\n");
    return 1;
  }
  text->insert(0, "%YAML:1.0\n---\n");
  return 2;
}

// Reads a {rows, cols, data} matrix under `key`; adds problems to `errors`. Returns false when
// the matrix is missing or malformed. expected_rows/cols < 0: any size.
bool ReadMatrix(const cv::FileStorage& fs, const char* key, int expected_rows, int expected_cols,
                bool required, std::vector<double>* data, int* rows_out, int* cols_out,
                std::ostringstream& errors) {
  const cv::FileNode node = fs[key];
  if (node.empty() || node.isNone()) {
    if (required) errors << key << ": missing; ";
    return false;
  }
  if (!node.isMap()) {
    errors << key << ": not a {rows, cols, data} map; ";
    return false;
  }
  const cv::FileNode rows_node = node["rows"], cols_node = node["cols"], data_node = node["data"];
  if (!rows_node.isInt() || !cols_node.isInt() || !data_node.isSeq()) {
    errors << key << ": needs integer rows, integer cols and a data list; ";
    return false;
  }
  const int rows = static_cast<int>(rows_node), cols = static_cast<int>(cols_node);
  if ((expected_rows >= 0 && rows != expected_rows) ||
      (expected_cols >= 0 && cols != expected_cols)) {
    errors << key << ": size " << rows << "x" << cols << ", expected " << expected_rows << "x"
           << expected_cols << "; ";
    return false;
  }
  if (rows < 0 || cols < 0 || static_cast<int>(data_node.size()) != rows * cols) {
    errors << key << ": data has " << data_node.size() << " values for " << rows << "x" << cols
           << "; ";
    return false;
  }
  data->clear();
  for (int i = 0; i < rows * cols; ++i) {
    const cv::FileNode v = data_node[i];
    if (!v.isReal() && !v.isInt()) {
      errors << key << ": data[" << i << "] is not a number; ";
      return false;
    }
    data->push_back(static_cast<double>(v));
    if (!std::isfinite(data->back())) {
      errors << key << ": data[" << i << "] = " << data->back() << " is not finite; ";
      return false;
    }
  }
  if (rows_out) *rows_out = rows;
  if (cols_out) *cols_out = cols;
  return true;
}

}  // namespace

void WritePinholeIntrinsics(const std::string& path, const PinholeBrownParameters& params,
                            const IntrinsicsFileExtras& extras) {
  std::string problems = CheckParameters(params);
  std::set<std::string> keys(std::begin(kRosKeys), std::end(kRosKeys));
  auto check_key = [&](const std::string& key) {
    if (!IsIdentifier(key)) {
      problems += "extra key \"" + key + "\" is not an identifier; ";
    } else if (!keys.insert(key).second) {
      problems += "extra key \"" + key + "\" is used twice or is a ROS key; ";
    }
  };
  for (const auto& [key, value] : extras.numbers) check_key(key);
  for (const auto& [key, value] : extras.strings) check_key(key);
  for (const auto& [key, value] : extras.number_lists) check_key(key);
  for (const auto& [key, value] : extras.string_lists) check_key(key);
  if (!problems.empty()) {
    problems.resize(problems.size() - 2);
    throw std::invalid_argument("intrinsics file \"" + path + "\": " + problems);
  }

  const bool rational =
      params.distortion[5] != 0.0 || params.distortion[6] != 0.0 || params.distortion[7] != 0.0;
  const double K[9] = {params.fx, 0, params.cx, 0, params.fy, params.cy, 0, 0, 1};
  const double R[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  // ROS: for a monocular camera P = [K | 0] (no rectification).
  const double P[12] = {params.fx, 0, params.cx, 0, 0, params.fy, params.cy, 0, 0, 0, 1, 0};

  std::ostringstream out;
  out << "%YAML 1.2\n---\n";
  out << "image_width: " << params.width << "\n";
  out << "image_height: " << params.height << "\n";
  out << "camera_name: " << Quoted(extras.camera_name) << "\n";
  WriteMatrix(out, "camera_matrix", 3, 3, K);
  out << "distortion_model: " << (rational ? "\"rational_polynomial\"" : "\"plumb_bob\"") << "\n";
  WriteMatrix(out, "distortion_coefficients", 1, rational ? 8 : 5, params.distortion.data());
  WriteMatrix(out, "rectification_matrix", 3, 3, R);
  WriteMatrix(out, "projection_matrix", 3, 4, P);
  for (const auto& [key, value] : extras.numbers) out << key << ": " << Number(value) << "\n";
  for (const auto& [key, value] : extras.strings) out << key << ": " << Quoted(value) << "\n";
  for (const auto& [key, values] : extras.number_lists) {
    out << key << ": [";
    for (size_t i = 0; i < values.size(); ++i) out << (i ? ", " : "") << Number(values[i]);
    out << "]\n";
  }
  for (const auto& [key, values] : extras.string_lists) {
    out << key << ": [";
    for (size_t i = 0; i < values.size(); ++i) out << (i ? ", " : "") << Quoted(values[i]);
    out << "]\n";
  }

  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  if (!file) {
    throw std::runtime_error("intrinsics file \"" + path +
                             "\": cannot open for writing: " + std::strerror(errno));
  }
  file << out.str();
  file.close();
  if (!file) throw std::runtime_error("intrinsics file \"" + path + "\": write failed");
}

PinholeBrownParameters ReadPinholeIntrinsics(const std::string& path, std::string* camera_name) {
  std::ifstream file(path, std::ios::binary);
  if (!file) {
    throw std::runtime_error("intrinsics file \"" + path +
                             "\": cannot open: " + std::strerror(errno));
  }
  std::stringstream buffer;
  buffer << file.rdbuf();
  std::string text = buffer.str();
  const int added_lines = PrepareForOpenCv(&text);

  cv::FileStorage fs;
  try {
    fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  } catch (const cv::Exception& e) {
    std::string what = e.what();
    const size_t at = what.find("error: ");
    if (at != std::string::npos) what = what.substr(at + 7);
    while (!what.empty() && (what.back() == '\n' || what.back() == ' ')) what.pop_back();
    throw std::runtime_error(
        "intrinsics file \"" + path + "\": not parsable as YAML (" + what +
        (added_lines ? "; line numbers count " + std::to_string(added_lines) + " added header lines"
                     : std::string()) +
        ")");
  }
  if (!fs.isOpened() || fs.root().empty()) {
    throw std::runtime_error("intrinsics file \"" + path + "\": empty or not a YAML map");
  }

  std::ostringstream errors;
  PinholeBrownParameters p;
  for (const char* key : {"image_width", "image_height"}) {
    const cv::FileNode node = fs[key];
    if (node.empty() || node.isNone()) {
      errors << key << ": missing; ";
    } else if (!node.isInt() || static_cast<int>(node) <= 0) {
      errors << key << ": must be a positive integer; ";
    } else {
      (std::strcmp(key, "image_width") == 0 ? p.width : p.height) = static_cast<int>(node);
    }
  }
  if (camera_name) {
    const cv::FileNode node = fs["camera_name"];
    *camera_name = node.isString() ? static_cast<std::string>(node) : std::string("unknown");
  }

  std::vector<double> K;
  if (ReadMatrix(fs, "camera_matrix", 3, 3, true, &K, nullptr, nullptr, errors)) {
    p.fx = K[0];
    p.fy = K[4];
    p.cx = K[2];
    p.cy = K[5];
    if (p.fx <= 0) errors << "camera_matrix: fx = data[0] = " << p.fx << " must be > 0; ";
    if (p.fy <= 0) errors << "camera_matrix: fy = data[4] = " << p.fy << " must be > 0; ";
    if (K[1] != 0) errors << "camera_matrix: skew data[1] = " << K[1] << " is not supported; ";
    if (K[3] != 0 || K[6] != 0 || K[7] != 0 || K[8] != 1) {
      errors << "camera_matrix: must have data[3] = 0 and last row [0, 0, 1], got " << K[3]
             << " and [" << K[6] << ", " << K[7] << ", " << K[8] << "]; ";
    }
  }

  std::string model = "plumb_bob";
  const cv::FileNode model_node = fs["distortion_model"];
  if (!model_node.empty() && !model_node.isNone()) {
    if (!model_node.isString()) {
      errors << "distortion_model: not a string; ";
    } else {
      model = static_cast<std::string>(model_node);
      if (model != "plumb_bob" && model != "rational_polynomial") {
        errors << "distortion_model: \"" << model
               << "\" is not supported (plumb_bob or rational_polynomial); ";
      }
    }
  }
  std::vector<double> D;
  int d_rows = 0, d_cols = 0;
  if (ReadMatrix(fs, "distortion_coefficients", -1, -1, true, &D, &d_rows, &d_cols, errors)) {
    const bool vector = d_rows == 1 || d_cols == 1;
    const size_t n = D.size();
    const bool size_ok = vector && (model == "rational_polynomial" ? n == 8 : (n == 4 || n == 5));
    if (!size_ok) {
      errors << "distortion_coefficients: size " << d_rows << "x" << d_cols << " does not fit "
             << model << " (" << (model == "rational_polynomial" ? "1x8" : "1x4 or 1x5") << "); ";
    } else {
      for (size_t i = 0; i < n; ++i) p.distortion[i] = D[i];
    }
  }
  std::vector<double> unused;
  ReadMatrix(fs, "rectification_matrix", 3, 3, false, &unused, nullptr, nullptr, errors);
  ReadMatrix(fs, "projection_matrix", 3, 4, false, &unused, nullptr, nullptr, errors);

  std::string message = errors.str();
  if (!message.empty()) {
    message.resize(message.size() - 2);
    throw std::invalid_argument("intrinsics file \"" + path + "\": " + message);
  }
  return p;
}

}  // namespace kinevis::vision
