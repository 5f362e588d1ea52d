#include "hal/camera/opencv_camera.h"

#include <glob.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <thread>
#include <utility>
#include <vector>

#include "hal/common/error.h"

namespace kinevis::hal {
namespace {

using Kind = OpenCvCameraOptions::Kind;
using namespace std::chrono_literals;

constexpr double kDefaultFps = 30.0;

const char* KindName(Kind kind) {
  switch (kind) {
    case Kind::kV4l2:
      return "v4l2";
    case Kind::kFile:
      return "file";
    case Kind::kImages:
      return "images";
  }
  return "?";
}

int CvType(PixelFormat format) {
  switch (format) {
    case PixelFormat::kMono8:
      return CV_8UC1;
    case PixelFormat::kBgr8:
    case PixelFormat::kRgb8:
      return CV_8UC3;
    case PixelFormat::kMono16:
      return CV_16UC1;
  }
  return CV_8UC1;
}

// What a decoded image becomes when no format was asked for; nullopt for layouts kinevis does
// not deliver (floating point, two channels).
std::optional<PixelFormat> NativeFormat(const cv::Mat& m) {
  const int channels = m.channels();
  if (m.depth() != CV_8U && m.depth() != CV_16U) return std::nullopt;
  if (channels == 1) return m.depth() == CV_8U ? PixelFormat::kMono8 : PixelFormat::kMono16;
  if (channels == 3 || channels == 4) return PixelFormat::kBgr8;
  return std::nullopt;
}

// Converts a decoded frame (8 or 16 bits; 1, 3 or 4 channels in OpenCV's BGR(A) order) into
// `out` as `format`, writing straight into out's buffer: OpenCV's create() keeps a destination
// whose size and type already match, so nothing is allocated once out is sized (a depth change
// goes through `scratch`, sized once too). False for a layout it cannot convert.
bool ConvertInto(const cv::Mat& src, PixelFormat format, cv::Mat* scratch, Image* out) {
  const int depth = src.depth();
  const int channels = src.channels();
  if ((depth != CV_8U && depth != CV_16U) || (channels != 1 && channels != 3 && channels != 4)) {
    return false;
  }
  out->Resize(src.cols, src.rows, format);
  cv::Mat dst(src.rows, src.cols, CvType(format), out->data.data(), out->stride);
  const bool mono = format == PixelFormat::kMono8 || format == PixelFormat::kMono16;
  const bool rgb = format == PixelFormat::kRgb8;
  const int dst_depth = format == PixelFormat::kMono16 ? CV_16U : CV_8U;
  int code = -1;  // -1: the channels already match
  if (channels == 1) {
    if (!mono) code = rgb ? cv::COLOR_GRAY2RGB : cv::COLOR_GRAY2BGR;
  } else if (channels == 3) {
    if (mono) {
      code = cv::COLOR_BGR2GRAY;
    } else if (rgb) {
      code = cv::COLOR_BGR2RGB;
    }
  } else {
    code = mono ? cv::COLOR_BGRA2GRAY : (rgb ? cv::COLOR_BGRA2RGB : cv::COLOR_BGRA2BGR);
  }
  if (depth == dst_depth) {
    if (code < 0) {
      src.copyTo(dst);
    } else {
      cv::cvtColor(src, dst, code);
    }
  } else {
    const cv::Mat* same_channels = &src;
    if (code >= 0) {
      cv::cvtColor(src, *scratch, code);
      same_channels = scratch;
    }
    // 8 -> 16 bits: 255 * 257 = 65535, full scale maps to full scale.
    same_channels->convertTo(dst, dst_depth, depth == CV_8U ? 257.0 : 1.0 / 257.0);
  }
  // OpenCV would have reallocated dst (leaving out untouched) on a size or type mismatch.
  return dst.data == out->data.data();
}

// The files a glob pattern names, directories left out, in byte order of their paths.
std::vector<std::string> GlobFiles(const std::string& pattern, int* glob_error) {
  std::vector<std::string> files;
  glob_t g{};
  *glob_error = ::glob(pattern.c_str(), GLOB_MARK, nullptr, &g);
  if (*glob_error == 0) {
    for (size_t i = 0; i < g.gl_pathc; ++i) {
      std::string path = g.gl_pathv[i];
      if (!path.empty() && path.back() != '/') files.push_back(std::move(path));
    }
  }
  globfree(&g);
  std::sort(files.begin(), files.end());
  return files;
}

std::string SizeText(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

common::Duration SecondsToDuration(double s) { return common::Duration(std::llround(s * 1e9)); }

bool PlausibleFps(double fps) { return std::isfinite(fps) && fps > 0.0 && fps <= 10'000.0; }

}  // namespace

struct OpenCvCamera::Impl {
  Impl(std::string n, OpenCvCameraOptions o, common::Clock& c)
      : name(std::move(n)), options(std::move(o)), clock(c) {}

  // What one read of the device gave.
  enum class ReadOutcome { kFrame, kSkipped, kFailed, kGone };

  void Open();
  void OpenV4l2();
  void OpenFile();
  void OpenImages();
  // Releases the source, joins the grabber and forgets the stream position.
  void Close();
  void SetFormat(int width, int height, PixelFormat pixel_format, double fps);

  std::error_code Start();
  void Stop();
  std::error_code Grab(Image* out, std::chrono::milliseconds timeout);
  // The next frame of a file or image sequence, without pacing.
  std::error_code GrabRecorded(Image* out);
  std::error_code GrabFile(Image* out);
  std::error_code GrabImages(Image* out);
  std::error_code GrabV4l2(Image* out, std::chrono::milliseconds timeout);
  std::error_code GrabLatest(Image* out, std::chrono::milliseconds timeout);
  bool ReadFileFrame();
  bool RewindFile();
  ReadOutcome ReadV4l2Frame(Image* image);
  void GrabberLoop();
  void V4l2GrabberLoop();
  void RecordedGrabberLoop();
  // Hands `back` over as the newest frame.
  void Publish();
  bool StopRequested();
  bool DeviceNodeExists() const;
  std::error_code Fault(const char* why);

  const std::string name;
  const OpenCvCameraOptions options;
  common::Clock& clock;
  std::atomic<common::DeviceLifecycle> lifecycle{common::DeviceLifecycle::kUnconfigured};
  AtomicCameraCounters counters;

  mutable std::mutex format_mutex;  // format is written by Open() and read from any thread
  CameraFormat format;
  // Copies of format's fields for the grab path, which must not take the lock.
  int width = 0;
  int height = 0;
  PixelFormat pixel_format = PixelFormat::kBgr8;
  double fps = kDefaultFps;
  common::Duration period{0};

  cv::VideoCapture capture;
  cv::Mat frame;              // the frame last read or decoded
  cv::Mat scratch;            // conversion temporary
  bool have_pending = false;  // `frame` holds a frame read by Open() and not yet delivered
  bool ended = false;         // end of a file or image sequence without loop

  // file: position in the recording
  uint64_t pass_frames = 0;              // frames read in this pass
  uint64_t frame_index = 0;              // index of `frame` in this pass
  uint64_t id_offset = 0;                // frames of the earlier passes
  common::Duration pass_offset{0};       // length of the earlier passes
  common::Duration frame_time{0};        // position of `frame` in this pass
  common::Duration last_stream_time{0};  // position of the last frame read in this pass

  // images
  std::vector<std::string> files;
  size_t next_file = 0;
  uint64_t pass = 0;
  bool decoded_in_pass = false;

  // v4l2
  uint64_t next_id = 0;
  bool have_last_stamp = false;
  common::Duration last_stamp{0};

  // latest: the grabber thread reads into `back` and swaps it with `latest`.
  std::thread grabber;
  std::mutex latest_mutex;
  std::condition_variable latest_cv;
  Image latest;
  Image back;
  uint64_t latest_seq = 0;  // frames published by the grabber
  uint64_t taken_seq = 0;   // the last one Grab() delivered
  bool stop_grabber = false;
  std::error_code grabber_error;
};

void OpenCvCamera::Impl::SetFormat(int w, int h, PixelFormat p, double f) {
  width = w;
  height = h;
  pixel_format = p;
  fps = f;
  period = SecondsToDuration(1.0 / f);
  std::lock_guard<std::mutex> lock(format_mutex);
  format = CameraFormat{w, h, p, f};
}

void OpenCvCamera::Impl::Open() {
  const common::DeviceLifecycle state = lifecycle.load();
  if (state == common::DeviceLifecycle::kConfigured || state == common::DeviceLifecycle::kActive)
    return;
  Close();
  std::vector<std::string> problems;
  if (options.path.empty()) problems.push_back("the path is empty");
  if ((options.width > 0) != (options.height > 0) || options.width < 0 || options.height < 0) {
    problems.push_back("width and height go together and are positive (width " +
                       std::to_string(options.width) + ", height " +
                       std::to_string(options.height) + ")");
  }
  if (options.width > 0 && options.kind != Kind::kV4l2) {
    problems.push_back("width and height apply to v4l2 only");
  }
  if (options.fps != 0.0 && !PlausibleFps(options.fps)) {
    problems.push_back("fps " + std::to_string(options.fps) + " is not in (0, 10000]");
  }
  if (!problems.empty()) {
    std::string all = "camera source \"" + name + "\": ";
    for (size_t i = 0; i < problems.size(); ++i) all += (i > 0 ? "; " : "") + problems[i];
    throw common::ConfigError(all);
  }
  try {
    switch (options.kind) {
      case Kind::kV4l2:
        OpenV4l2();
        break;
      case Kind::kFile:
        OpenFile();
        break;
      case Kind::kImages:
        OpenImages();
        break;
    }
  } catch (...) {
    Close();
    throw;
  }
  lifecycle = common::DeviceLifecycle::kConfigured;
  spdlog::info(
      "{}: {} source open, {}x{} {} at {} fps{}", name, KindName(options.kind), width, height,
      ToString(pixel_format), fps,
      options.intrinsics_id.empty() ? "" : ", intrinsics \"" + options.intrinsics_id + "\"");
}

void OpenCvCamera::Impl::OpenV4l2() {
  const std::string& path = options.path;
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    throw HalError(name, "open", "no such device \"" + path + "\": " + ErrnoText(errno));
  }
  if (!S_ISCHR(st.st_mode)) {
    throw HalError(name, "open", "\"" + path + "\" is not a device node (character device)");
  }
  if (!capture.open(path, cv::CAP_V4L2)) {
    throw HalError(name, "open",
                   "OpenCV's V4L2 backend cannot open \"" + path +
                       "\" (not a video capture device, busy, or no permission)");
  }
  if (options.width > 0) {
    capture.set(cv::CAP_PROP_FRAME_WIDTH, options.width);
    capture.set(cv::CAP_PROP_FRAME_HEIGHT, options.height);
  }
  if (options.fps > 0.0) capture.set(cv::CAP_PROP_FPS, options.fps);
  const int w = static_cast<int>(capture.get(cv::CAP_PROP_FRAME_WIDTH));
  const int h = static_cast<int>(capture.get(cv::CAP_PROP_FRAME_HEIGHT));
  if (w <= 0 || h <= 0) {
    throw HalError(name, "get format", "the device reports a size of " + SizeText(w, h));
  }
  if (options.width > 0 && (w != options.width || h != options.height)) {
    throw HalError(name, "set capture size",
                   "asked " + SizeText(options.width, options.height) + ", the device gives " +
                       SizeText(w, h));
  }
  double f = capture.get(cv::CAP_PROP_FPS);
  if (options.fps > 0.0 && PlausibleFps(f) && std::abs(f - options.fps) > 0.01 * options.fps) {
    spdlog::warn("{}: asked {} fps, the device runs at {} fps", name, options.fps, f);
  }
  if (!PlausibleFps(f)) f = options.fps > 0.0 ? options.fps : kDefaultFps;
  SetFormat(w, h, options.format.value_or(PixelFormat::kBgr8), f);
}

void OpenCvCamera::Impl::OpenFile() {
  const std::string& path = options.path;
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    throw HalError(name, "open", "no such file \"" + path + "\": " + ErrnoText(errno));
  }
  if (S_ISDIR(st.st_mode)) {
    throw HalError(name, "open", "\"" + path + "\" is a directory, not a video file");
  }
  if (!capture.open(path, cv::CAP_ANY)) {
    throw HalError(name, "open",
                   "OpenCV cannot read \"" + path + "\" as a video (unknown container or codec)");
  }
  double f = options.fps;
  if (f <= 0.0) {
    f = capture.get(cv::CAP_PROP_FPS);
    if (!PlausibleFps(f)) {
      spdlog::warn("{}: the container gives no frame rate; assuming {} fps (set fps=F)", name,
                   kDefaultFps);
      f = kDefaultFps;
    }
  }
  period = SecondsToDuration(1.0 / f);  // ReadFileFrame() needs it before SetFormat()
  fps = f;
  if (!ReadFileFrame()) {
    throw HalError(name, "open", "\"" + path + "\" has no frame OpenCV can decode");
  }
  const std::optional<PixelFormat> native = NativeFormat(frame);
  if (!native) {
    throw HalError(name, "open", "\"" + path + "\" decodes to an unsupported pixel type");
  }
  have_pending = true;
  SetFormat(frame.cols, frame.rows, options.format.value_or(*native), f);
}

void OpenCvCamera::Impl::OpenImages() {
  int glob_error = 0;
  files = GlobFiles(options.path, &glob_error);
  if (glob_error == GLOB_ABORTED) {
    throw HalError(name, "open",
                   "cannot read the directory of \"" + options.path + "\": " + ErrnoText(errno));
  }
  if (files.empty()) {
    throw HalError(name, "open", "no file matches \"" + options.path + "\"");
  }
  for (size_t i = 0; i < files.size(); ++i) {
    frame = cv::imread(files[i], cv::IMREAD_UNCHANGED);
    if (!frame.empty() && NativeFormat(frame)) {
      next_file = i;
      have_pending = true;
      break;
    }
    ++counters.decode_errors;
    spdlog::warn("{}: cannot decode \"{}\"; skipped", name, files[i]);
  }
  if (!have_pending) {
    throw HalError(name, "open",
                   "none of the " + std::to_string(files.size()) + " files matching \"" +
                       options.path + "\" decodes as an image (first: \"" + files.front() + "\")");
  }
  const double f = options.fps > 0.0 ? options.fps : kDefaultFps;
  SetFormat(frame.cols, frame.rows, options.format.value_or(*NativeFormat(frame)), f);
}

void OpenCvCamera::Impl::Close() {
  Stop();
  capture.release();
  frame.release();
  have_pending = false;
  ended = false;
  pass_frames = frame_index = id_offset = 0;
  pass_offset = frame_time = last_stream_time = common::Duration{0};
  files.clear();
  next_file = 0;
  pass = 0;
  decoded_in_pass = false;
  next_id = 0;
  have_last_stamp = false;
  last_stamp = common::Duration{0};
}

std::error_code OpenCvCamera::Impl::Start() {
  const common::DeviceLifecycle state = lifecycle.load();
  if (state == common::DeviceLifecycle::kActive) return {};
  if (state != common::DeviceLifecycle::kConfigured) return Errc::kNotActive;
  if (options.latest) {
    {
      std::lock_guard<std::mutex> lock(latest_mutex);
      stop_grabber = false;
      grabber_error = {};
      latest_seq = taken_seq = 0;
    }
    grabber = std::thread([this] { GrabberLoop(); });
  }
  lifecycle = common::DeviceLifecycle::kActive;
  return {};
}

void OpenCvCamera::Impl::Stop() {
  if (grabber.joinable()) {
    {
      std::lock_guard<std::mutex> lock(latest_mutex);
      stop_grabber = true;
    }
    grabber.join();
  }
  if (lifecycle.load() == common::DeviceLifecycle::kActive)
    lifecycle = common::DeviceLifecycle::kConfigured;
}

std::error_code OpenCvCamera::Impl::Fault(const char* why) {
  lifecycle = common::DeviceLifecycle::kFault;
  spdlog::error("{}: {}; camera in fault", name, why);
  return Errc::kClosed;
}

std::error_code OpenCvCamera::Impl::Grab(Image* out, std::chrono::milliseconds timeout) {
  const common::DeviceLifecycle state = lifecycle.load();
  if (state == common::DeviceLifecycle::kFault) return Errc::kClosed;
  if (state != common::DeviceLifecycle::kActive) return Errc::kNotActive;
  if (options.latest) return GrabLatest(out, timeout);
  const std::error_code ec =
      options.kind == Kind::kV4l2 ? GrabV4l2(out, timeout) : GrabRecorded(out);
  if (!ec) ++counters.frames;
  return ec;
}

std::error_code OpenCvCamera::Impl::GrabRecorded(Image* out) {
  return options.kind == Kind::kFile ? GrabFile(out) : GrabImages(out);
}

bool OpenCvCamera::Impl::ReadFileFrame() {
  if (!capture.read(frame) || frame.empty()) return false;
  frame_index = pass_frames++;
  if (options.fps > 0.0) {
    frame_time = SecondsToDuration(static_cast<double>(frame_index) / fps);
  } else {
    const double ms = capture.get(cv::CAP_PROP_POS_MSEC);
    frame_time =
        std::isfinite(ms) && ms > 0.0 ? SecondsToDuration(ms / 1000.0) : common::Duration{0};
    // A container without presentation times (or one that repeats them) still gets strictly
    // increasing stamps, one nominal period apart.
    if (frame_index > 0 && frame_time <= last_stream_time) {
      frame_time = last_stream_time + period;
    }
  }
  last_stream_time = frame_time;
  return true;
}

bool OpenCvCamera::Impl::RewindFile() {
  pass_offset += last_stream_time + period;
  id_offset += pass_frames;
  pass_frames = 0;
  last_stream_time = common::Duration{0};
  // Reopening is the one rewind every container and backend supports (seeking to frame 0 is
  // approximate for some codecs).
  capture.release();
  return capture.open(options.path, cv::CAP_ANY);
}

std::error_code OpenCvCamera::Impl::GrabFile(Image* out) {
  while (true) {
    if (ended) return Errc::kClosed;
    if (have_pending) {
      have_pending = false;
    } else if (!ReadFileFrame()) {
      if (!options.loop || pass_frames == 0) {
        ended = true;
        spdlog::info("{}: end of the recording after {} frames", name, id_offset + pass_frames);
        return Errc::kClosed;
      }
      if (!RewindFile()) return Fault("cannot reopen the file to loop");
      continue;
    }
    const uint64_t id = id_offset + frame_index;
    if (frame.cols != width || frame.rows != height) {
      ++counters.decode_errors;
      spdlog::warn("{}: frame {} is {}, the recording {}; skipped", name, id,
                   SizeText(frame.cols, frame.rows), SizeText(width, height));
      continue;
    }
    if (!ConvertInto(frame, pixel_format, &scratch, out)) {
      ++counters.decode_errors;
      spdlog::warn("{}: frame {} has an unsupported pixel type; skipped", name, id);
      continue;
    }
    out->timestamp = pass_offset + frame_time;
    out->frame_id = id;
    out->intrinsics_id = options.intrinsics_id;
    return {};
  }
}

std::error_code OpenCvCamera::Impl::GrabImages(Image* out) {
  while (true) {
    if (ended) return Errc::kClosed;
    if (next_file >= files.size()) {
      if (!options.loop || !decoded_in_pass) {
        ended = true;
        spdlog::info("{}: end of the image sequence", name);
        return Errc::kClosed;
      }
      ++pass;
      next_file = 0;
      decoded_in_pass = false;
      continue;
    }
    const size_t index = next_file++;
    const std::string& path = files[index];
    if (have_pending) {
      have_pending = false;  // decoded by Open()
    } else {
      frame = cv::imread(path, cv::IMREAD_UNCHANGED);
      if (frame.empty()) {
        ++counters.decode_errors;
        // Once per file is enough: later passes log quietly.
        if (pass == 0) {
          spdlog::warn("{}: cannot decode \"{}\"; skipped", name, path);
        } else {
          spdlog::debug("{}: cannot decode \"{}\"; skipped", name, path);
        }
        continue;
      }
    }
    if (frame.cols != width || frame.rows != height) {
      ++counters.decode_errors;
      spdlog::warn("{}: \"{}\" is {}, the sequence {}; skipped", name, path,
                   SizeText(frame.cols, frame.rows), SizeText(width, height));
      continue;
    }
    if (!ConvertInto(frame, pixel_format, &scratch, out)) {
      ++counters.decode_errors;
      spdlog::warn("{}: \"{}\" has an unsupported pixel type; skipped", name, path);
      continue;
    }
    decoded_in_pass = true;
    const uint64_t id = pass * files.size() + index;
    out->timestamp = SecondsToDuration(static_cast<double>(id) / fps);
    out->frame_id = id;
    out->intrinsics_id = options.intrinsics_id;
    return {};
  }
}

bool OpenCvCamera::Impl::DeviceNodeExists() const {
  struct stat st {};
  return ::stat(options.path.c_str(), &st) == 0;
}

OpenCvCamera::Impl::ReadOutcome OpenCvCamera::Impl::ReadV4l2Frame(Image* image) {
  if (!capture.grab()) return DeviceNodeExists() ? ReadOutcome::kFailed : ReadOutcome::kGone;
  const common::Duration now = clock.Now();
  if (!capture.retrieve(frame) || frame.empty()) {
    ++counters.decode_errors;
    spdlog::warn("{}: a frame could not be decoded; skipped", name);
    return ReadOutcome::kSkipped;
  }
  // The driver's buffer stamp is CLOCK_MONOTONIC, which is the steady clock's; on any other
  // clock it is implausible and the time of hand-over is taken instead.
  common::Duration stamp = now;
  const double ms = capture.get(cv::CAP_PROP_POS_MSEC);
  if (std::isfinite(ms) && ms > 0.0) {
    const common::Duration driver = SecondsToDuration(ms / 1000.0);
    if (driver <= now && now - driver < 1s) stamp = driver;
  }
  if (have_last_stamp && stamp <= last_stamp) {
    ++counters.duplicates;
    return ReadOutcome::kSkipped;
  }
  if (frame.cols != width || frame.rows != height) {
    ++counters.decode_errors;
    spdlog::warn("{}: a frame of {} arrived, the stream is {}; skipped", name,
                 SizeText(frame.cols, frame.rows), SizeText(width, height));
    return ReadOutcome::kSkipped;
  }
  if (!ConvertInto(frame, pixel_format, &scratch, image)) {
    ++counters.decode_errors;
    spdlog::warn("{}: a frame has an unsupported pixel type; skipped", name);
    return ReadOutcome::kSkipped;
  }
  uint64_t missed = 0;
  if (have_last_stamp && (stamp - last_stamp) * 2 > period * 3) {
    const double periods = std::chrono::duration<double>(stamp - last_stamp).count() * fps;
    missed = static_cast<uint64_t>(std::max(0LL, std::llround(periods) - 1));
  }
  counters.dropped += missed;
  next_id += missed;
  image->timestamp = stamp;
  image->frame_id = next_id++;
  image->intrinsics_id = options.intrinsics_id;
  last_stamp = stamp;
  have_last_stamp = true;
  return ReadOutcome::kFrame;
}

std::error_code OpenCvCamera::Impl::GrabV4l2(Image* out, std::chrono::milliseconds timeout) {
  const common::Duration deadline =
      clock.Now() + std::chrono::duration_cast<common::Duration>(timeout);
  while (true) {
    switch (ReadV4l2Frame(out)) {
      case ReadOutcome::kFrame:
        return {};
      case ReadOutcome::kGone:
        return Fault("the device node vanished (unplugged?)");
      case ReadOutcome::kFailed:
        ++counters.timeouts;
        spdlog::warn("{}: no frame from the device", name);
        return Errc::kTimeout;
      case ReadOutcome::kSkipped:
        if (clock.Now() >= deadline) {
          ++counters.timeouts;
          return Errc::kTimeout;
        }
        break;
    }
  }
}

bool OpenCvCamera::Impl::StopRequested() {
  std::lock_guard<std::mutex> lock(latest_mutex);
  return stop_grabber;
}

void OpenCvCamera::Impl::Publish() {
  {
    std::lock_guard<std::mutex> lock(latest_mutex);
    if (latest_seq > taken_seq) ++counters.dropped;  // replaced before anyone took it
    std::swap(latest, back);
    ++latest_seq;
  }
  latest_cv.notify_all();
}

void OpenCvCamera::Impl::GrabberLoop() {
  if (options.kind == Kind::kV4l2) {
    V4l2GrabberLoop();
  } else {
    RecordedGrabberLoop();
  }
}

void OpenCvCamera::Impl::V4l2GrabberLoop() {
  while (!StopRequested()) {
    const ReadOutcome outcome = ReadV4l2Frame(&back);
    if (outcome == ReadOutcome::kGone) {
      {
        std::lock_guard<std::mutex> lock(latest_mutex);
        grabber_error = Errc::kClosed;
      }
      latest_cv.notify_all();
      return;
    }
    if (outcome == ReadOutcome::kFailed) {
      // OpenCV's read already waited its select() timeout; keep trying while the node exists.
      spdlog::warn("{}: no frame from the device", name);
      continue;
    }
    if (outcome == ReadOutcome::kFrame) Publish();
  }
}

// A recording replayed as a live camera: frame i is published when the clock has moved by its
// distance in the recording from the first frame of this Start(), so a slow reader misses
// frames exactly as it would on a real camera.
void OpenCvCamera::Impl::RecordedGrabberLoop() {
  bool first = true;
  common::Duration first_stamp{0};
  common::Duration clock_start{0};
  while (!StopRequested()) {
    const std::error_code ec = GrabRecorded(&back);
    if (ec) {
      {
        std::lock_guard<std::mutex> lock(latest_mutex);
        grabber_error = ec;
      }
      latest_cv.notify_all();
      return;
    }
    if (first) {
      first = false;
      first_stamp = back.timestamp;
      clock_start = clock.Now();
    }
    const common::Duration due = clock_start + (back.timestamp - first_stamp);
    // Sleep in slices so that Stop() is not held up by a long gap in the recording.
    for (common::Duration now = clock.Now(); now < due; now = clock.Now()) {
      if (StopRequested()) {
        ++counters.dropped;  // read but never published
        return;
      }
      clock.SleepUntil(std::min(due, now + common::Duration(10ms)));
    }
    Publish();
  }
}

std::error_code OpenCvCamera::Impl::GrabLatest(Image* out, std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(latest_mutex);
  if (!latest_cv.wait_for(lock, timeout,
                          [&] { return latest_seq > taken_seq || bool(grabber_error); })) {
    ++counters.timeouts;
    return Errc::kTimeout;
  }
  if (latest_seq == taken_seq) {
    // The grabber ended: the device vanished (a fault), or the recording ended without loop
    // (kClosed, the camera stays active), or it could not be reopened to loop (already a fault).
    const std::error_code ec = grabber_error;
    lock.unlock();
    if (options.kind == Kind::kV4l2) return Fault("the device node vanished (unplugged?)");
    return ec;
  }
  out->Resize(latest.width, latest.height, latest.format);
  std::memcpy(out->data.data(), latest.data.data(), out->data.size());
  out->timestamp = latest.timestamp;
  out->frame_id = latest.frame_id;
  out->intrinsics_id = latest.intrinsics_id;
  taken_seq = latest_seq;
  ++counters.frames;
  return {};
}

OpenCvCamera::OpenCvCamera(std::string name, OpenCvCameraOptions options, common::Clock& clock)
    : impl_(std::make_unique<Impl>(std::move(name), std::move(options), clock)) {}

OpenCvCamera::~OpenCvCamera() { impl_->Stop(); }

const std::string& OpenCvCamera::name() const { return impl_->name; }

common::DeviceLifecycle OpenCvCamera::lifecycle() const { return impl_->lifecycle.load(); }

void OpenCvCamera::Open() { impl_->Open(); }

std::error_code OpenCvCamera::Start() { return impl_->Start(); }

void OpenCvCamera::Stop() { impl_->Stop(); }

std::error_code OpenCvCamera::Grab(Image* out, std::chrono::milliseconds timeout) {
  return impl_->Grab(out, timeout);
}

CameraFormat OpenCvCamera::format() const {
  std::lock_guard<std::mutex> lock(impl_->format_mutex);
  return impl_->format;
}

const std::string& OpenCvCamera::intrinsics_id() const { return impl_->options.intrinsics_id; }

CameraCounters OpenCvCamera::counters() const { return impl_->counters.Snapshot(); }

}  // namespace kinevis::hal
