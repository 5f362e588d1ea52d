#include "vision/cloud/ply.h"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__,
              "ply.cc copies little-endian floats byte for byte; add byte swapping for this host");

namespace kinevis::vision::cloud {
namespace {

struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f != nullptr) std::fclose(f);
  }
};

[[noreturn]] void Fail(const std::string& path, const std::string& what) {
  throw std::invalid_argument("PLY file " + path + ": " + what);
}

// Size in bytes of a PLY scalar type, 0 when unknown.
int ScalarSize(const std::string& type) {
  if (type == "char" || type == "uchar" || type == "int8" || type == "uint8") return 1;
  if (type == "short" || type == "ushort" || type == "int16" || type == "uint16") return 2;
  if (type == "int" || type == "uint" || type == "int32" || type == "uint32") return 4;
  if (type == "float" || type == "float32") return 4;
  if (type == "double" || type == "float64") return 8;
  return 0;
}

bool IsFloat(const std::string& type) { return type == "float" || type == "float32"; }

struct Property {
  std::string name;
  std::string type;
  int offset = 0;
};

struct Element {
  std::string name;
  std::size_t count = 0;
  std::vector<Property> properties;
  int stride = 0;
  bool has_list = false;
};

}  // namespace

void WritePly(const std::string& path, const PointCloud& cloud,
              const std::vector<std::string>& comments) {
  const std::string problem = cloud.Validate();
  if (!problem.empty()) {
    throw std::invalid_argument("PLY file " + path + ": cannot write the cloud: " + problem);
  }
  std::ostringstream header;
  header << "ply\nformat binary_little_endian 1.0\ncomment kinevis point cloud, units m\n";
  for (const std::string& c : comments) {
    if (c.find_first_of("\r\n") != std::string::npos) {
      throw std::invalid_argument("PLY file " + path + ": comment '" + c + "' holds a newline");
    }
    header << "comment " << c << "\n";
  }
  header << "element vertex " << cloud.size() << "\n"
         << "property float x\nproperty float y\nproperty float z\n";
  if (cloud.has_normals()) header << "property float nx\nproperty float ny\nproperty float nz\n";
  if (cloud.has_confidence()) header << "property float confidence\n";
  header << "end_header\n";

  const std::size_t floats = 3 + (cloud.has_normals() ? 3 : 0) + (cloud.has_confidence() ? 1 : 0);
  std::unique_ptr<std::FILE, FileCloser> file(std::fopen(path.c_str(), "wb"));
  if (!file) throw std::runtime_error("PLY file " + path + ": cannot open for writing");
  const std::string text = header.str();
  bool ok = std::fwrite(text.data(), 1, text.size(), file.get()) == text.size();
  // Interleave in blocks so that a 1e6-point cloud needs no second full-size copy.
  constexpr std::size_t kBlock = 1 << 16;
  std::vector<float> buffer(kBlock * floats);
  for (std::size_t first = 0; ok && first < cloud.size(); first += kBlock) {
    const std::size_t count = std::min(kBlock, cloud.size() - first);
    float* out = buffer.data();
    for (std::size_t i = first; i < first + count; ++i) {
      std::memcpy(out, cloud.points[i].data(), 3 * sizeof(float));
      out += 3;
      if (cloud.has_normals()) {
        std::memcpy(out, cloud.normals[i].data(), 3 * sizeof(float));
        out += 3;
      }
      if (cloud.has_confidence()) *out++ = cloud.confidence[i];
    }
    ok = std::fwrite(buffer.data(), sizeof(float) * floats, count, file.get()) == count;
  }
  if (std::fclose(file.release()) != 0) ok = false;
  if (!ok) throw std::runtime_error("PLY file " + path + ": write failed (disk full?)");
}

PointCloud ReadPly(const std::string& path, std::vector<std::string>* comments) {
  std::ifstream in(path, std::ios::binary);
  if (!in) Fail(path, "cannot open (missing or unreadable)");
  std::string line;
  std::getline(in, line);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line != "ply") Fail(path, "not a PLY file (first line is not 'ply')");

  std::vector<Element> elements;
  bool format_seen = false;
  int line_number = 1;
  bool ended = false;
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    const std::string where = "header line " + std::to_string(line_number) + " ('" + line + "')";
    if (keyword == "end_header") {
      ended = true;
      break;
    } else if (keyword == "format") {
      std::string format, version;
      words >> format >> version;
      if (format != "binary_little_endian") {
        Fail(path,
             where + ": format " + format + " is not supported; expected binary_little_endian");
      }
      format_seen = true;
    } else if (keyword == "comment") {
      if (comments != nullptr) comments->push_back(line.size() > 8 ? line.substr(8) : "");
    } else if (keyword == "obj_info" || keyword.empty()) {
    } else if (keyword == "element") {
      Element e;
      long long count = -1;
      words >> e.name >> count;
      if (e.name.empty() || count < 0 || words.fail()) Fail(path, where + ": bad element line");
      e.count = static_cast<std::size_t>(count);
      elements.push_back(e);
    } else if (keyword == "property") {
      if (elements.empty()) Fail(path, where + ": property before any element");
      Element& e = elements.back();
      std::string type;
      words >> type;
      if (type == "list") {
        e.has_list = true;
        continue;
      }
      Property p;
      words >> p.name;
      p.type = type;
      const int size = ScalarSize(type);
      if (size == 0 || p.name.empty()) Fail(path, where + ": unknown property type '" + type + "'");
      p.offset = e.stride;
      e.stride += size;
      e.properties.push_back(p);
    } else {
      Fail(path, where + ": unknown keyword '" + keyword + "'");
    }
  }
  if (!ended) Fail(path, "no end_header (truncated header)");
  if (!format_seen) Fail(path, "no format line in the header");
  if (elements.empty() || elements.front().name != "vertex") {
    Fail(path, "the first element is not 'vertex'");
  }
  const Element& vertex = elements.front();
  if (vertex.has_list) Fail(path, "the vertex element has a list property (not supported)");

  const auto find = [&](const char* name) -> const Property* {
    for (const Property& p : vertex.properties) {
      if (p.name == name) {
        if (!IsFloat(p.type)) {
          Fail(path, std::string("vertex property ") + name + " is " + p.type + "; expected float");
        }
        return &p;
      }
    }
    return nullptr;
  };
  const Property* xyz[3] = {find("x"), find("y"), find("z")};
  for (int k = 0; k < 3; ++k) {
    if (xyz[k] == nullptr) Fail(path, std::string("vertex property ") + "xyz"[k] + " is missing");
  }
  const Property* nxyz[3] = {find("nx"), find("ny"), find("nz")};
  const int normal_count = (nxyz[0] != nullptr) + (nxyz[1] != nullptr) + (nxyz[2] != nullptr);
  if (normal_count != 0 && normal_count != 3) {
    Fail(path, "vertex has only some of nx, ny, nz; expected all three or none");
  }
  const Property* conf = find("confidence");

  const std::streampos body_start = in.tellg();
  in.seekg(0, std::ios::end);
  const std::size_t available = static_cast<std::size_t>(in.tellg() - body_start);
  const std::size_t stride = static_cast<std::size_t>(vertex.stride);
  const std::size_t needed = vertex.count * stride;
  if (vertex.count != 0 && (stride == 0 || needed / stride != vertex.count)) {
    Fail(path, "vertex count " + std::to_string(vertex.count) + " is too large");
  }
  if (available < needed) {
    Fail(path, "truncated: " + std::to_string(vertex.count) + " vertices need " +
                   std::to_string(needed) + " bytes, the file has " + std::to_string(available));
  }
  std::vector<char> body(needed);
  in.seekg(body_start);
  if (needed > 0 && !in.read(body.data(), static_cast<std::streamsize>(needed))) {
    Fail(path, "read error in the body");
  }

  PointCloud cloud;
  cloud.points.resize(vertex.count);
  if (normal_count == 3) cloud.normals.resize(vertex.count);
  if (conf != nullptr) cloud.confidence.resize(vertex.count);
  const bool packed = xyz[0]->offset == 0 && xyz[1]->offset == 4 && xyz[2]->offset == 8;
  for (std::size_t i = 0; i < vertex.count; ++i) {
    const char* record = body.data() + i * stride;
    Eigen::Vector3f& p = cloud.points[i];
    if (packed) {
      std::memcpy(p.data(), record, 3 * sizeof(float));
    } else {
      for (int k = 0; k < 3; ++k) std::memcpy(&p[k], record + xyz[k]->offset, sizeof(float));
    }
    if (!p.allFinite()) Fail(path, "vertex " + std::to_string(i) + " has a non-finite coordinate");
    if (normal_count == 3) {
      Eigen::Vector3f& n = cloud.normals[i];
      for (int k = 0; k < 3; ++k) std::memcpy(&n[k], record + nxyz[k]->offset, sizeof(float));
      if (!n.allFinite() || (!n.isZero(0.0f) && std::abs(n.norm() - 1.0f) > 1e-3f)) {
        std::ostringstream what;
        what << "vertex " << i << " has a normal of length " << n.norm() << "; expected 1 or 0";
        Fail(path, what.str());
      }
    }
    if (conf != nullptr) {
      float c;
      std::memcpy(&c, record + conf->offset, sizeof(float));
      if (!(c >= 0.0f && c <= 1.0f)) {
        std::ostringstream what;
        what << "vertex " << i << " has confidence " << c << "; expected within [0, 1]";
        Fail(path, what.str());
      }
      cloud.confidence[i] = c;
    }
  }
  return cloud;
}

}  // namespace kinevis::vision::cloud
