// Scanned maps (issue 7, seed 004 eq. 51–55): 1,000,000 stripe points to a cloud in the base
// frame with normals, and its PLY written and read back.
#include <benchmark/benchmark.h>

#include <filesystem>

#include "calibration/weld_mount/scan_cloud.h"
#include "vision/cloud/ply.h"

namespace {

using kinevis::calibration::ScanLine;

// 1000 stripes of 1000 points over a gently curved surface 0.4 m ahead, the scanner moving by
// θ1 steps between stripes.
std::vector<ScanLine> Lines() {
  std::vector<ScanLine> lines(1000);
  for (int l = 0; l < 1000; ++l) {
    lines[l].q << 2e-4 * l, 0.0, 0.2, 0.0, 0.0;
    for (int i = 0; i < 1000; ++i) {
      const double x = -0.05 + 1e-4 * i;
      lines[l].p_C.emplace_back(x, 0.0, 0.4 + 0.5 * x * x);
    }
  }
  return lines;
}

const kinevis::robots::Weld5Model& Robot() {
  static const kinevis::robots::Weld5Model robot =
      kinevis::robots::Weld5Model::Seed(kinevis::robots::Weld5TorchTransform(0.025, 0.250, 0.0));
  return robot;
}

Eigen::Isometry3d Mount() {
  return Eigen::Translation3d(-0.05, -0.06, 0.1) * Eigen::Isometry3d::Identity();
}

void BM_ScansToCloudWithNormals_1M(benchmark::State& state) {
  const std::vector<ScanLine> lines = Lines();
  kinevis::calibration::ScanCloudOptions options;
  options.normals.radius = 0.6e-3;
  for (auto _ : state) {
    const kinevis::calibration::ScanCloud c =
        kinevis::calibration::ScansToCloud(Robot(), Mount(), lines, options);
    benchmark::DoNotOptimize(c.cloud.normals.data());
    state.counters["missing"] = static_cast<double>(c.normals.missing);
  }
}
BENCHMARK(BM_ScansToCloudWithNormals_1M)->Unit(benchmark::kMillisecond);

void BM_ScansToCloudNoNormals_1M(benchmark::State& state) {
  const std::vector<ScanLine> lines = Lines();
  kinevis::calibration::ScanCloudOptions options;
  options.estimate_normals = false;
  for (auto _ : state) {
    const kinevis::calibration::ScanCloud c =
        kinevis::calibration::ScansToCloud(Robot(), Mount(), lines, options);
    benchmark::DoNotOptimize(c.cloud.points.data());
  }
}
BENCHMARK(BM_ScansToCloudNoNormals_1M)->Unit(benchmark::kMillisecond);

void BM_PlyWriteRead_1M(benchmark::State& state) {
  kinevis::calibration::ScanCloudOptions options;
  options.estimate_normals = false;
  kinevis::vision::cloud::PointCloud cloud =
      kinevis::calibration::ScansToCloud(Robot(), Mount(), Lines(), options).cloud;
  cloud.normals.assign(cloud.size(), Eigen::Vector3f::UnitZ());
  const std::string path =
      (std::filesystem::temp_directory_path() / "kinevis_weld_mount_bench.ply").string();
  for (auto _ : state) {
    kinevis::vision::cloud::WritePly(path, cloud);
    const kinevis::vision::cloud::PointCloud back = kinevis::vision::cloud::ReadPly(path);
    benchmark::DoNotOptimize(back.points.data());
  }
  std::filesystem::remove(path);
}
BENCHMARK(BM_PlyWriteRead_1M)->Unit(benchmark::kMillisecond);

}  // namespace
