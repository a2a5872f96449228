#include "acquisition/sim_camera.h"

#include <cstring>
#include <filesystem>
#include <stdexcept>

#include "acquisition/camera_drivers.h"
#include "core/config_reader.h"
#include "core/error.h"
#include "core/format.h"
#include "core/image.h"
#include "core/srgb.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>

namespace flamerig {

const char* ToString(TriggerMode mode) {
  switch (mode) {
    case TriggerMode::kFreeRun:
      return "free-run";
    case TriggerMode::kSoftware:
      return "software";
    case TriggerMode::kHardware:
      return "hardware";
    case TriggerMode::kAction:
      return "action";
  }
  return "?";
}

TriggerMode TriggerModeFromName(const std::string& name) {
  for (TriggerMode m : {TriggerMode::kFreeRun, TriggerMode::kSoftware, TriggerMode::kHardware,
                        TriggerMode::kAction})
    if (name == ToString(m)) return m;
  throw InputError("trigger mode '" + name + "': use free-run, software, hardware or action");
}

void CameraSettings::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("camera settings: " + what); };
  if (width < 0 || height < 0 || width > 16384 || height > 16384)
    fail("width and height must be in [0, 16384] (0: the sensor's size)");
  if (offset_x < 0 || offset_y < 0 || offset_x > 16384 || offset_y > 16384)
    fail("offset_x and offset_y must be in [0, 16384]");
  if (!(frame_rate_hz > 0) || !(frame_rate_hz <= 100000)) fail("frame_rate_hz must be in (0, 1e5]");
  if (!(exposure_us > 0) || !std::isfinite(exposure_us)) fail("exposure_us must be > 0");
  if (!(exposure_us <= 1e6 / frame_rate_hz))
    fail("exposure_us must not exceed the frame period (" + std::to_string(1e6 / frame_rate_hz) +
         " us)");
  if (!(gain_db >= -100 && gain_db <= 100)) fail("gain_db must be in [-100, 100]");
  if (packet_size < 0) fail("packet_size must be >= 0");
  if (!wire_format.empty()) {
    const WireFormat* w = WireFormatFromName(wire_format);
    if (!w)
      fail("wire format '" + wire_format + "' is not one flamerig unpacks");
    else if (pixel_format != w->stored)
      fail("wire format '" + wire_format + "' is unpacked into " + ToString(w->stored) + ", not " +
           ToString(pixel_format));
  }
}

void CameraSettings::SetPixelFormat(const std::string& name) {
  if (const WireFormat* w = WireFormatFromName(name)) {
    pixel_format = w->stored;
    wire_format = w->name;
    return;
  }
  try {
    pixel_format = PixelFormatFromName(name);
    wire_format.clear();
  } catch (const InputError& e) {
    throw InputError(std::string(e.what()) +
                     "; or, from an aravis camera (or a sim one), Mono10, Mono12, Mono14, "
                     "Mono10Packed, Mono12Packed, Mono10p or Mono12p (unpacked into Mono16), or "
                     "BayerRG10, BayerRG12, BayerRG10Packed, BayerRG12Packed, BayerRG10p or "
                     "BayerRG12p and their GR, GB and BG layouts (unpacked into BayerRG16, ...)");
  }
}

std::string CameraSettings::pixel_format_name() const {
  return wire_format.empty() ? ToString(pixel_format) : wire_format;
}

void SimTriggerBus::Fire(std::int64_t trigger_id, std::int64_t monotonic_ns) {
  std::lock_guard<std::mutex> lock(mutex_);
  pulses_.push_back({trigger_id, monotonic_ns});
}

std::vector<SimTriggerBus::Pulse> SimTriggerBus::Since(std::size_t from) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (from >= pulses_.size()) return {};
  return std::vector<Pulse>(pulses_.begin() + static_cast<std::ptrdiff_t>(from), pulses_.end());
}

std::size_t SimTriggerBus::count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return pulses_.size();
}

ImageSource TestPatternSource() {
  return [](const FrameInfo& info, std::vector<std::uint8_t>* bytes) {
    // Byte b of pixel (x, y) is x + 2y + 3 frame_id + 50 camera + 7b (mod 256): along a row the
    // pixels step by one, so every row is the same ramp entered at another place. The ramp is built
    // once per thread and size, and a frame costs one copy per row, as a driver copying out of its
    // DMA buffer does (a loop over bytes made this test double most of the capture benchmark's
    // CPU: 62% of its samples under perf, 2026-11-26).
    const int bpp = BytesPerPixel(info.pixel_format);
    const std::size_t row_bytes = static_cast<std::size_t>(info.width) * bpp;
    bytes->resize(row_bytes * info.height);
    thread_local std::vector<std::uint8_t> ramp;
    const std::size_t ramp_pixels = static_cast<std::size_t>(info.width) + 256;
    if (ramp.size() != ramp_pixels * bpp) {
      ramp.resize(ramp_pixels * bpp);
      for (std::size_t i = 0; i < ramp_pixels; ++i)
        for (int b = 0; b < bpp; ++b) ramp[i * bpp + b] = static_cast<std::uint8_t>(i + 7 * b);
    }
    const std::uint64_t base = 3 * info.frame_id + 50 * static_cast<std::uint64_t>(info.camera);
    for (int y = 0; y < info.height; ++y) {
      const std::size_t start = (2 * static_cast<std::uint64_t>(y) + base) % 256;
      std::memcpy(bytes->data() + y * row_bytes, ramp.data() + start * bpp, row_bytes);
    }
    // Camera and frame id in the first bytes, little-endian.
    const std::uint64_t stamp[2] = {static_cast<std::uint64_t>(info.camera), info.frame_id};
    for (std::size_t i = 0; i < 16 && i < bytes->size(); ++i)
      (*bytes)[i] = static_cast<std::uint8_t>(stamp[i / 8] >> (8 * (i % 8)));
  };
}

namespace {

// Why a replay of a deeper camera's codes refuses `taken` (exposure us x gain as a factor) of
// `whose` ("this frame's", "this camera's"), against its reference.
std::string DeepReplayRefusal(const ReplayExposure& replay, const std::string& whose,
                              double taken) {
  return std::string("holds a deeper camera's codes, which replay as they are, at ") +
         (replay.dataset_reference
              ? "the exposure " +
                    (std::filesystem::path(replay.dataset_dir) / "dataset.yaml").string() +
                    " states"
              : std::string("the settings of the config's first camera replaying it")) +
         " only (exposure us x gain as a factor: " + FormatNumber(replay.reference->load()) + "; " +
         whose + " " + FormatNumber(taken) + "): configure the camera at those";
}

}  // namespace

DatasetExposureStatement ReadDatasetExposure(const std::string& dataset_dir) {
  DatasetExposureStatement stated;
  const std::filesystem::path path = std::filesystem::path(dataset_dir) / "dataset.yaml";
  stated.path = path.string();
  if (!std::filesystem::exists(path)) return stated;
  YAML::Node dataset;
  try {
    dataset = YAML::LoadFile(stated.path)["dataset"];
  } catch (const YAML::Exception& e) {
    throw InputError(stated.path + ": not a dataset.yaml (" + e.what() + ")");
  }
  if (!dataset || dataset.IsNull()) return stated;
  if (!dataset.IsMap())
    throw InputError(stated.path + ": `dataset` is not a map of the dataset's keys");
  auto read = [&](const char* key, const char* what) {
    const YAML::Node node = dataset[key];
    if (!node || node.IsNull()) return 0.0;
    double v = 0;
    try {
      v = node.as<double>();
    } catch (const YAML::Exception& e) {
      throw InputError(stated.path + ": dataset." + key + ": " + e.what());
    }
    if (!(v > 0) || !std::isfinite(v))
      throw InputError(stated.path + ": dataset." + key + " must be a positive number" + what +
                       ", not " + FormatNumber(v));
    return v;
  };
  stated.exposure = read("exposure", "");
  stated.unit_us = read("exposure_unit_us", " (a time in microseconds)");
  if (stated.unit_us > 0 && !(stated.exposure > 0))
    throw InputError(stated.path + ": dataset.exposure is missing, and exposure_unit_us (" +
                     FormatNumber(stated.unit_us) + " us) is the time of an exposure it states");
  if (!std::isfinite(stated.reference_us()))
    throw InputError(stated.path + ": dataset.exposure x exposure_unit_us overflows");
  return stated;
}

ImageSource DatasetReplaySource(const std::string& dataset_dir, const std::string& camera,
                                ReplayContent content, std::shared_ptr<ReplayExposure> exposure) {
  namespace fs = std::filesystem;
  // One frame: 8-bit sRGB images, or 16-bit codes from a deeper camera (3 channels either way).
  struct Replayed {
    ImageU8 u8;
    ImageU16 u16;
    std::string path;
    bool deep() const { return u16.width > 0; }
    int width() const { return deep() ? u16.width : u8.width; }
    int height() const { return deep() ? u16.height : u8.height; }
  };
  auto images = std::make_shared<std::vector<Replayed>>();
  auto read = [&](const fs::path& path) {
    Replayed r;
    r.path = path.string();
    ReadImage(r.path, &r.u8, &r.u16, 3);
    images->push_back(std::move(r));
  };
  if (content == ReplayContent::kFire) {
    for (int k = 0;; ++k) {
      char name[32];
      std::snprintf(name, sizeof name, "frame_%06d", k);
      const fs::path path = fs::path(dataset_dir) / "frames" / name / (camera + ".png");
      if (!fs::exists(path)) break;
      read(path);
    }
    if (images->empty()) {
      throw InputError("replay of " + dataset_dir + ": no frames/frame_000000/" + camera + ".png");
    }
  } else {
    // One frame per board view; a view this camera did not see shows a dark frame (the board was
    // elsewhere), sized like the camera's other views.
    std::vector<fs::path> views;
    const fs::path dir = fs::path(dataset_dir) / "calibration";
    if (fs::is_directory(dir))
      for (const auto& e : fs::directory_iterator(dir))
        if (e.is_directory()) views.push_back(e.path());
    std::sort(views.begin(), views.end());
    int width = 0, height = 0;
    std::vector<int> missing;
    for (const auto& v : views) {
      const fs::path path = v / (camera + ".png");
      if (fs::exists(path)) {
        read(path);
        width = images->back().width();
        height = images->back().height();
      } else {
        missing.push_back(static_cast<int>(images->size()));
        images->emplace_back();
      }
    }
    if (width == 0)
      throw InputError("replay of " + dataset_dir + ": no calibration/*/" + camera + ".png");
    for (int k : missing) (*images)[k].u8 = ImageU8(width, height, 3, 8);
  }
  // The exposure x gain the dataset's frames show: the dataset's own, stated in time; or else the
  // reference's (ReplayExposure), or else the first frame's. A deeper camera's codes cannot
  // follow a change.
  if (!exposure) exposure = std::make_shared<ReplayExposure>();
  exposure->dataset_dir = dataset_dir;
  if (content == ReplayContent::kFire)
    if (const double own = ReadDatasetExposure(dataset_dir).reference_us(); own > 0) {
      exposure->reference = std::make_shared<std::atomic<double>>(own);
      exposure->sets_reference = false;
      exposure->dataset_reference = true;
    }
  exposure->scalable =
      std::none_of(images->begin(), images->end(), [](const Replayed& r) { return r.deep(); });
  return [images, dataset_dir, camera, exposure](const FrameInfo& info,
                                                 std::vector<std::uint8_t>* bytes) {
    const Replayed& img = (*images)[info.frame_id % images->size()];
    // An 8-bit frame's light scales with the camera's exposure and gain against the reference's:
    // its sRGB values through a table, linear light times the factor, clipped at full scale.
    std::atomic<double>& reference = *exposure->reference;
    const double taken = info.exposure_us * std::pow(10.0, info.gain_db / 20.0);
    double factor = 1.0;
    if (taken > 0 && std::isfinite(taken)) {
      double expected = 0.0;
      reference.compare_exchange_strong(expected, taken);
      factor = taken / reference.load();
    }
    if (img.deep() && std::abs(factor - 1) > 1e-9) {
      throw InputError("replay of " + dataset_dir + " camera " + camera + ": " + img.path + " " +
                       DeepReplayRefusal(*exposure, "this frame's", taken));
    }
    std::array<std::uint8_t, 256> scaled;
    const bool rescale = factor != 1.0 && !img.deep();
    if (rescale) {
      const auto& linear = SrgbU8ToLinearTable();
      for (int v = 0; v < 256; ++v) scaled[v] = QuantizeU8(SrgbEncode(factor * linear[v]));
    }
    auto code8 = [&](std::size_t k) {
      return rescale ? scaled[img.u8.pixels[k]] : img.u8.pixels[k];
    };
    if (img.width() != info.width || img.height() != info.height) {
      throw InputError("replay of " + dataset_dir + " camera " + camera + ": images are " +
                       std::to_string(img.width()) + "x" + std::to_string(img.height()) +
                       ", the camera is set to " + std::to_string(info.width) + "x" +
                       std::to_string(info.height));
    }
    const bool wide = BytesPerPixel(info.pixel_format) == 2;
    if (img.deep() && !wide) {
      throw InputError("replay of " + dataset_dir + " camera " + camera + ": " + img.path +
                       " holds a deeper camera's 16-bit codes; its frames cannot be sent as " +
                       ToString(info.pixel_format) + " (use Mono16 or a Bayer 16 format)");
    }
    // A camera sending a wire format (Mono12p, ...) puts a deeper camera's codes in the words'
    // high bits, as its driver unpacks them; it cannot send codes deeper than the format.
    const WireFormat* wire = WireFormatFromCode(info.sent_pfnc);
    const int shift = wire && wire->stored == info.pixel_format && img.deep() ? 16 - wire->bits : 0;
    const std::size_t n = std::size_t(info.width) * info.height;
    bytes->resize(n * BytesPerPixel(info.pixel_format));
    // Channel c of pixel i at full scale: an 8-bit code, or in 16 bits the deeper camera's code as
    // it is and an 8-bit one x 257.
    auto value = [&](std::size_t i, int c) -> double {
      return img.deep() ? img.u16.pixels[3 * i + c] : code8(3 * i + c) * (wide ? 257 : 1);
    };
    auto luma = [&](std::size_t i) {
      return 0.2126 * value(i, 0) + 0.7152 * value(i, 1) + 0.0722 * value(i, 2);
    };
    auto put = [&](std::size_t i, double v) {
      if (wide) {
        const long code = std::lround(v);
        if (shift > 0 && code >> (16 - shift) != 0) {
          throw InputError("replay of " + dataset_dir + " camera " + camera + ": " + img.path +
                           " holds code " + std::to_string(code) + ", deeper than " + wire->name +
                           " sends (" + std::to_string(wire->bits) + " bits)");
        }
        const auto w = static_cast<std::uint16_t>(code << shift);
        std::memcpy(bytes->data() + 2 * i, &w, 2);
      } else {
        (*bytes)[i] = static_cast<std::uint8_t>(std::lround(v));
      }
    };
    // GenICam Bayer names: the colours of the first row's two sites, then the second row's.
    const char* cell = BayerCell(info.pixel_format);
    auto bayer_channel = [&](std::size_t i) {
      const std::size_t x = i % info.width, y = i / info.width;
      const char c = cell[2 * (y % 2) + (x % 2)];
      return c == 'R' ? 0 : c == 'G' ? 1 : 2;
    };
    for (std::size_t i = 0; i < n; ++i) {
      switch (info.pixel_format) {
        case PixelFormat::kMono8:
        case PixelFormat::kMono16:
          put(i, luma(i));
          break;
        case PixelFormat::kRgb8:
          for (int c = 0; c < 3; ++c) (*bytes)[3 * i + c] = code8(3 * i + c);
          break;
        default:
          put(i, value(i, bayer_channel(i)));
      }
    }
  };
}

SimCamera::SimCamera(const SimCameraOptions& options, Clock* clock, SimTriggerBus* bus)
    : options_(options),
      clock_(clock),
      bus_(bus),
      rng_(options.seed),
      unwrapper_(options.frame_id_bits, 1),
      source_(options.source ? options.source : TestPatternSource()) {
  if (!clock_) throw InputError("sim camera '" + options.id + "': no clock");
  for (double p :
       {options.drop_probability, options.late_probability, options.incomplete_probability}) {
    if (!(p >= 0 && p <= 1))
      throw InputError("sim camera '" + options.id + "': probabilities must be in [0, 1]");
  }
  if (options.jitter_ns < 0 || options.transfer_ns < 0 || options.trigger_latency_ns < 0 ||
      options.late_ns < 0)
    throw InputError("sim camera '" + options.id + "': times must be >= 0");
  if (const int i = FirstInvalidOutage(options.outages); i >= 0)
    throw InputError("sim camera '" + options.id + "': outage " + std::to_string(i + 1) +
                     " must end after it starts and after the one before it");
}

int FirstInvalidOutage(const std::vector<SimOutage>& outages) {
  for (std::size_t i = 0; i < outages.size(); ++i) {
    const SimOutage& o = outages[i];
    const bool ordered = i == 0 || (outages[i - 1].up_ns >= 0 && o.down_ns >= outages[i - 1].up_ns);
    if (o.down_ns < 0 || (o.up_ns >= 0 && o.up_ns <= o.down_ns) || !ordered) return int(i);
  }
  return -1;
}

CameraDescription SimCamera::description() const {
  return CameraDescription{
      "sim", options_.id, "flamerig", "simulated camera", "sim://" + options_.id, options_.id};
}

void SimCamera::Configure(const CameraSettings& settings) {
  if (running_) throw InputError("sim camera '" + options_.id + "': configure it while stopped");
  try {
    settings.Validate();
  } catch (const InputError& e) {
    throw InputError("sim camera '" + options_.id + "': " + e.what());
  }
  if (settings.trigger == TriggerMode::kAction)
    throw InputError("sim camera '" + options_.id +
                     "': GigE Vision action commands reach real cameras only");
  if (!settings.features.empty())
    throw InputError("sim camera '" + options_.id + "': feature '" + settings.features[0].first +
                     "': sim cameras have no GenICam features");
  if (settings.trigger == TriggerMode::kHardware && !bus_) {
    throw InputError("sim camera '" + options_.id +
                     "': hardware trigger needs a trigger bus (TriggerSource " +
                     settings.trigger_source + " is not wired)");
  }
  settings_ = settings;
  const WireFormat* wire = WireFormatFromName(settings_.wire_format);
  wire_pfnc_ = wire ? wire->pfnc : 0;
  wire_bits_ = wire ? wire->bits : 0;
  if (settings_.width == 0) settings_.width = 640;  // the simulated sensor
  if (settings_.height == 0) settings_.height = 480;
  live_exposure_us_ = settings_.exposure_us;
  live_gain_db_ = settings_.gain_db;
  // A replay shows its dataset as it is at the reference's settings: its dataset's own, or else
  // the first replaying camera's, which sets them. A deeper camera's codes cannot show it at
  // others.
  if (options_.replay_exposure) {
    ReplayExposure& replay = *options_.replay_exposure;
    const double product = settings_.exposure_us * std::pow(10.0, settings_.gain_db / 20.0);
    if (replay.sets_reference) {
      *replay.reference = product;
    } else if (!replay.scalable && *replay.reference > 0 &&
               std::abs(product / *replay.reference - 1) > 1e-9) {
      throw InputError("sim camera '" + options_.id + "': its replay " +
                       DeepReplayRefusal(replay, "this camera's", product));
    }
  }
}

CameraSettings SimCamera::settings() const {
  CameraSettings s = settings_;
  s.exposure_us = live_exposure_us_;
  s.gain_db = live_gain_db_;
  return s;
}

bool SimCamera::SetExposureGainLive(double exposure_us, double gain_db) {
  // A deeper camera's replayed codes cannot follow: configure it while stopped instead.
  if (options_.replay_exposure && !options_.replay_exposure->scalable) return false;
  live_exposure_us_ = exposure_us;
  live_gain_db_ = gain_db;
  return true;
}

void SimCamera::Start(int buffers) {
  if (buffers < 1) throw InputError("sim camera '" + options_.id + "': buffers >= 1");
  pool_.Reserve(static_cast<std::size_t>(buffers), FrameBytes());
  running_ = true;
  started_ns_ = clock_->MonotonicNs();
  if (settings_.frame_rate_hz > 0) {
    const auto period_ns = static_cast<std::int64_t>(std::llround(1e9 / settings_.frame_rate_hz));
    free_run_first_ns_ =
        period_ns > 0 ? (started_ns_ + period_ns - 1) / period_ns * period_ns : started_ns_;
  } else {
    free_run_first_ns_ = started_ns_;
  }
  produced_ = 0;
  pending_.clear();
  bus_position_ = bus_ ? bus_->count() : 0;  // pulses before the start are not seen
  device_counter_ = options_.first_frame_id;
  last_exposure_ns_ = started_ns_;
  std::lock_guard<std::mutex> lock(trigger_mutex_);
  software_triggers_.clear();  // triggers sent while stopped are not seen
}

void SimCamera::Stop() {
  running_ = false;
  pending_.clear();
}

bool SimCamera::Gone(std::int64_t t) const {
  for (const SimOutage& o : options_.outages)
    if (t >= o.down_ns && (o.up_ns < 0 || t < o.up_ns)) return true;
  return false;
}

bool SimCamera::connected() const { return !Gone(clock_->MonotonicNs()); }

void SimCamera::SoftwareTrigger(std::int64_t trigger_id) {
  std::lock_guard<std::mutex> lock(trigger_mutex_);
  software_triggers_.push_back(trigger_id);
  // The pulse time is when the call was made.
  software_triggers_.push_back(clock_->MonotonicNs());
}

void SimCamera::AddExposure(std::int64_t start_ns, std::int64_t trigger_id) {
  ++produced_;  // exposures attempted (time passes while the camera is gone too)
  if (Gone(start_ns)) return;
  std::uniform_real_distribution<double> u(0, 1);
  Pending p;
  p.info.camera = options_.camera_index;
  p.info.device_frame_id = device_counter_;
  const std::uint64_t top = options_.frame_id_bits >= 64
                                ? ~std::uint64_t(0)
                                : (std::uint64_t(1) << options_.frame_id_bits) - 1;
  device_counter_ = device_counter_ >= top ? 1 : device_counter_ + 1;
  // The device clock: offset and drift relative to the host.
  p.info.device_timestamp_ns =
      options_.device_offset_ns + start_ns +
      static_cast<std::int64_t>(std::llround(double(start_ns) * options_.drift_ppm * 1e-6));
  p.info.trigger_id = trigger_id;
  p.info.exposure_us = live_exposure_us_;
  p.info.gain_db = live_gain_db_;
  p.info.pixel_format = settings_.pixel_format;
  p.info.width = settings_.width;
  p.info.height = settings_.height;
  p.dropped = u(rng_) < options_.drop_probability;
  const bool late = u(rng_) < options_.late_probability;
  p.info.status =
      u(rng_) < options_.incomplete_probability ? FrameStatus::kIncomplete : FrameStatus::kOk;
  p.deliver_ns = start_ns + static_cast<std::int64_t>(p.info.exposure_us * 1e3) +
                 options_.transfer_ns + (late ? options_.late_ns : 0);
  auto it = std::upper_bound(pending_.begin(), pending_.end(), p.deliver_ns,
                             [](std::int64_t t, const Pending& q) { return t < q.deliver_ns; });
  pending_.insert(it, p);
}

void SimCamera::Produce(std::int64_t until_ns) {
  std::normal_distribution<double> jitter(0.0, double(options_.jitter_ns));
  auto jittered = [&](std::int64_t t) {
    return options_.jitter_ns > 0 ? t + static_cast<std::int64_t>(std::llround(jitter(rng_))) : t;
  };
  if (settings_.trigger == TriggerMode::kFreeRun) {
    const double period_ns = 1e9 / settings_.frame_rate_hz * (1.0 + options_.drift_ppm * 1e-6);
    while (true) {
      const std::int64_t nominal =
          free_run_first_ns_ +
          static_cast<std::int64_t>(std::llround(double(produced_) * period_ns));
      if (nominal > until_ns) break;
      AddExposure(jittered(nominal), -1);
    }
    return;
  }
  std::vector<SimTriggerBus::Pulse> pulses;
  if (settings_.trigger == TriggerMode::kHardware) {
    for (const auto& p : bus_->Since(bus_position_)) {
      if (p.monotonic_ns + options_.trigger_latency_ns > until_ns) break;
      pulses.push_back(p);
    }
    bus_position_ += pulses.size();
  } else {
    std::lock_guard<std::mutex> lock(trigger_mutex_);
    while (software_triggers_.size() >= 2 &&
           software_triggers_[1] + options_.trigger_latency_ns <= until_ns) {
      pulses.push_back({software_triggers_[0], software_triggers_[1]});
      software_triggers_.pop_front();
      software_triggers_.pop_front();
    }
  }
  const std::int64_t min_gap = static_cast<std::int64_t>(1e9 / settings_.frame_rate_hz);
  for (const auto& p : pulses) {
    const std::int64_t start = jittered(p.monotonic_ns + options_.trigger_latency_ns);
    // A trigger that comes before the sensor is ready (faster than the maximum rate) is ignored,
    // as real cameras do.
    if (produced_ > 0 && start - last_exposure_ns_ < min_gap) {
      ++triggers_ignored_;
      continue;
    }
    // A trigger lost on its way (a loose trigger cable, a dropped software trigger command).
    if (options_.miss_trigger_probability > 0 &&
        std::uniform_real_distribution<double>(0, 1)(rng_) < options_.miss_trigger_probability) {
      ++triggers_ignored_;
      continue;
    }
    last_exposure_ns_ = start;
    AddExposure(start, p.trigger_id);
  }
}

std::optional<Frame> SimCamera::Pop(std::int64_t timeout_ns) {
  if (!running_) throw std::logic_error("sim camera '" + options_.id + "': Pop before Start");
  const std::int64_t deadline = clock_->MonotonicNs() + std::max<std::int64_t>(0, timeout_ns);
  for (;;) {
    Produce(deadline);
    if (pending_.empty() || pending_.front().deliver_ns > deadline) {
      // Nothing due yet: look again for trigger pulses every millisecond until the deadline, as a
      // camera that exposes on a trigger would.
      const std::int64_t now = clock_->MonotonicNs();
      if (now >= deadline) break;
      std::int64_t wake = std::min(deadline, now + 1'000'000);
      if (!pending_.empty()) wake = std::min(wake, pending_.front().deliver_ns);
      clock_->SleepUntil(wake);
      continue;
    }
    Pending p = pending_.front();
    pending_.pop_front();
    clock_->SleepUntil(p.deliver_ns);
    if (p.dropped) continue;  // the frame id advanced; the host never sees it
    Frame f;
    f.info = p.info;
    f.info.frame_id = unwrapper_.Next(p.info.device_frame_id);
    f.info.host_monotonic_ns = clock_->MonotonicNs();
    f.info.host_realtime_ns = clock_->RealtimeNs();
    // A pooled buffer (frame_pool.h), filled as a driver copies out of its DMA buffer.
    // What it sends: its stored format, or a wire format, whose words keep their high bits only
    // (as the driver unpacks them: wire_bits_ set by Configure).
    f.info.sent_pfnc = wire_pfnc_ ? wire_pfnc_ : PfncOf(f.info.pixel_format);
    auto bytes = pool_.Acquire(FrameBytes());
    source_(f.info, bytes.get());
    if (wire_bits_ > 0) {
      const std::uint16_t keep = static_cast<std::uint16_t>(0xffffu << (16 - wire_bits_));
      for (std::size_t i = 0; i + 1 < bytes->size(); i += 2) {
        std::uint16_t w;
        std::memcpy(&w, bytes->data() + i, 2);
        w &= keep;
        std::memcpy(bytes->data() + i, &w, 2);
      }
    }
    f.data = std::move(bytes);
    counters_.missing_by_id = unwrapper_.missing();
    counters_.buffers_allocated = pool_.stats().allocated;
    if (settings_.trigger == TriggerMode::kFreeRun && last_timestamp_ns_ >= 0) {
      const double period = 1e9 / settings_.frame_rate_hz;
      const double gap = double(f.info.device_timestamp_ns - last_timestamp_ns_) / period;
      if (gap > 1.5) counters_.missing_by_time += static_cast<std::uint64_t>(std::llround(gap)) - 1;
    }
    last_timestamp_ns_ = f.info.device_timestamp_ns;
    ++counters_.delivered;
    if (f.info.status != FrameStatus::kOk) ++counters_.incomplete;
    return f;
  }
  ++counters_.timeouts;
  return std::nullopt;
}

namespace {

// The replay references of the cameras read so far, by config file, dataset and content: a
// camera joins the one its config's earlier cameras made for the same dataset (and does not set
// it), or makes it, at its own configured settings (so that the reference holds before any camera
// is configured, and when the first camera is not there to be: a deferred camera). A camera read
// at an index no later than the last one read for the key starts a new reading of the config,
// and a new reference. Held weakly: entries whose cameras are gone are dropped.
void ShareReplayReference(const std::string& config_path, const std::filesystem::path& dataset,
                          const std::string& content, int index, const CameraSettings& settings,
                          ReplayExposure* exposure) {
  struct Entry {
    std::weak_ptr<std::atomic<double>> reference;
    int last_index = -1;
  };
  static std::mutex mutex;
  static std::map<std::string, Entry> shared;
  std::error_code ec;
  const std::filesystem::path canonical = std::filesystem::weakly_canonical(dataset, ec);
  const std::string key = config_path + '\n' + (ec ? dataset : canonical).string() + '\n' + content;
  const std::lock_guard<std::mutex> lock(mutex);
  for (auto it = shared.begin(); it != shared.end();)
    it = it->second.reference.expired() && it->first != key ? shared.erase(it) : std::next(it);
  Entry& entry = shared[key];
  auto reference = entry.reference.lock();
  if (reference && index > entry.last_index) {
    exposure->reference = std::move(reference);
    exposure->sets_reference = false;
  } else {
    *exposure->reference = settings.exposure_us * std::pow(10.0, settings.gain_db / 20.0);
    entry.reference = exposure->reference;
  }
  entry.last_index = index;
}

// The sim driver's keys (acquisition/capture.h documents them).
void ReadSimKeys(const YAML::Node& keys, const std::string& where, const std::string& config_path,
                 int index, CaptureCameraConfig* camera) {
  namespace fs = std::filesystem;
  SimCameraOptions o;
  o.id = camera->id;
  o.camera_index = index;
  o.seed = static_cast<std::uint64_t>(index) + 1;
  if (keys) {
    ConfigReader sr(keys, where);
    o.seed = sr.Whole<std::uint64_t>("seed", double(o.seed), 0, 9e15);
    o.drop_probability = sr.NonNegative("drop_probability", 0);
    o.miss_trigger_probability = sr.NonNegative("miss_trigger_probability", 0);
    o.plugged = sr.Get<std::string>("plugged", "");
    if (!o.plugged.empty() && !fs::path(o.plugged).is_absolute())
      o.plugged = (fs::path(config_path).parent_path() / o.plugged).string();
    o.late_probability = sr.NonNegative("late_probability", 0);
    o.incomplete_probability = sr.NonNegative("incomplete_probability", 0);
    o.jitter_ns = static_cast<std::int64_t>(sr.Range("jitter_us", 0, 0, 1e9) * 1e3);
    o.drift_ppm = sr.Range("drift_ppm", 0, -1e5, 1e5);
    const std::string replay = sr.Get<std::string>("replay", "");
    const std::string replay_content = sr.Get<std::string>("replay_content", "fire");
    if (replay_content != "fire" && replay_content != "calibration")
      throw InputError(where + ": 'replay_content' must be fire or calibration");
    if (!replay.empty()) {
      // Relative to the config file's folder, like every path in a config.
      const fs::path dataset = fs::path(replay).is_absolute()
                                   ? fs::path(replay)
                                   : fs::path(config_path).parent_path() / replay;
      try {
        o.replay_exposure = std::make_shared<ReplayExposure>();
        o.source = DatasetReplaySource(
            dataset.string(), camera->name,
            replay_content == "fire" ? ReplayContent::kFire : ReplayContent::kCalibration,
            o.replay_exposure);
        // Unless the dataset states its own, the cameras of this config replaying the same
        // dataset share its reference, which the first of them sets (ReplayExposure). Before
        // any frame: the source reads the reference it points to then.
        if (o.replay_exposure->sets_reference)
          ShareReplayReference(config_path, dataset, replay_content, index, camera->settings,
                               o.replay_exposure.get());
      } catch (const std::exception& e) {
        throw InputError(where + ".replay: " + e.what());
      }
    }
    // Outages: disconnect_at_s / reconnect_at_s for one, `outages: [[down_s, up_s], ...]` for
    // several (up_s = -1: for good); seconds from the daemon's start.
    const double d = sr.Range("disconnect_at_s", -1, -1, 1e9),
                 re = sr.Range("reconnect_at_s", -1, -1, 1e9);
    auto ns = [](double s) { return s < 0 ? std::int64_t(-1) : std::llround(s * 1e9); };
    if (d >= 0) o.outages.push_back({ns(d), ns(re)});
    if (re >= 0 && d < 0) throw InputError(where + ": 'reconnect_at_s' needs 'disconnect_at_s'");
    const auto outages = sr.Get<std::vector<std::vector<double>>>("outages", {});
    for (std::size_t i = 0; i < outages.size(); ++i) {
      const auto& pair = outages[i];
      if (pair.size() != 2 || !(pair[0] >= 0 && pair[0] <= 1e9) ||
          !(pair[1] == -1 || (pair[1] > pair[0] && pair[1] <= 1e9)))
        throw InputError(where + ".outages[" + std::to_string(i) +
                         "]: must be [down_s, up_s] with 0 <= down_s < up_s, or "
                         "up_s = -1 (for good)");
      o.outages.push_back({ns(pair[0]), ns(pair[1])});
    }
    if (FirstInvalidOutage(o.outages) >= 0)
      throw InputError(where +
                       ": outages must be in order and not overlap (the "
                       "disconnect_at_s one first)");
    for (double p : {o.drop_probability, o.late_probability, o.incomplete_probability,
                     o.miss_trigger_probability})
      if (p > 1) throw InputError(where + ": probabilities must be in [0, 1]");
    sr.CheckKnown();
  }
  camera->options = o;
}

}  // namespace

CameraDriver SimCameraDriver() {
  CameraDriver d;
  d.name = "sim";
  d.description = "simulated cameras: a deterministic clock, trigger line, drops and outages";
  d.capabilities.trigger_ids = true;
  d.default_id = [](int index) { return "SIM" + std::to_string(index); };
  d.read_keys = &ReadSimKeys;
  d.open = [](const CaptureCameraConfig& camera, int,
              const DriverContext& context) -> std::unique_ptr<Camera> {
    // The config's outage times count from now.
    SimCameraOptions o = camera.Options<SimCameraOptions>();
    if (!o.plugged.empty() && !std::filesystem::exists(o.plugged))
      throw IoError("sim camera " + camera.id + " is not plugged in (no " + o.plugged + ")");
    const std::int64_t now = context.clock->MonotonicNs();
    for (SimOutage& outage : o.outages) {
      outage.down_ns += now;
      if (outage.up_ns >= 0) outage.up_ns += now;
    }
    return std::make_unique<SimCamera>(o, context.clock, context.sim_trigger_line);
  };
  return d;
}

}  // namespace flamerig
