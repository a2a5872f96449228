#include "pipeline/simulate.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>

#include "acquisition/camera.h"
#include "core/atomic_file.h"
#include "core/config_reader.h"
#include "core/error.h"
#include "fitting/camera_response.h"
#include "pipeline/frame_source.h"
#include "pipeline/picture.h"
#include "pipeline/radiometric_calibration.h"
#include "pipeline/video_codec.h"
#include "tomography/vdb_io.h"

namespace flamerig {
namespace {

namespace fs = std::filesystem;

[[noreturn]] void Fail(const std::string& path, const std::string& field, const std::string& rule) {
  throw InputError(path + ": field '" + field + "': " + rule);
}

template <typename T>
void Read(const YAML::Node& map, const char* key, T* value, const std::string& path,
          const std::string& prefix) {
  YAML::Node node = map[key];
  if (!node) return;
  try {
    *value = node.as<T>();
  } catch (const YAML::Exception&) {
    Fail(path, prefix + key, "has the wrong type");
  }
}

Eigen::Vector3d ReadVec3(const YAML::Node& node, const std::string& path,
                         const std::string& field) {
  if (!node.IsSequence() || node.size() != 3) Fail(path, field, "must be a list of 3 numbers");
  Eigen::Vector3d v;
  for (int i = 0; i < 3; ++i) {
    try {
      v[i] = node[i].as<double>();
    } catch (const YAML::Exception&) {
      Fail(path, field, "element " + std::to_string(i) + " is not a number");
    }
  }
  return v;
}

std::string FrameName(int f) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "frame_%06d", f);
  return buffer;
}

}  // namespace

namespace {

// One frame through the codec, as an intra-coded video frame; a mono frame as grey RGB, back to
// one channel (the mean of the decoded three).
ImageU8 ThroughCodec(const ImageU8& frame, const VideoCodecOptions& codec) {
  if (frame.channels == 3) return ThroughVideoCodec({frame}, codec)[0];
  ImageU8 rgb(frame.width, frame.height, 3);
  for (std::size_t p = 0; p < frame.num_pixels(); ++p)
    for (int c = 0; c < 3; ++c) rgb.pixels[3 * p + c] = frame.pixels[p];
  const ImageU8 back = ThroughVideoCodec({rgb}, codec)[0];
  ImageU8 out(frame.width, frame.height, 1);
  for (std::size_t p = 0; p < out.num_pixels(); ++p)
    out.pixels[p] = static_cast<std::uint8_t>(
        (back.pixels[3 * p] + back.pixels[3 * p + 1] + back.pixels[3 * p + 2] + 1) / 3);
  return out;
}

// The keys of the `simulate:` map `s` into `c` (SimulateConfig::Load).
void ReadMaps(const YAML::Node& s, const std::string& path, SimulateConfig* out) {
  SimulateConfig& c = *out;
  CheckKeys(s,
            {"seed", "frames", "frame_rate_hz", "absorption", "grid_resolution", "noise_dn",
             "exposure", "fire", "box", "rig", "calibration", "render", "radiometry",
             "camera_gains", "camera_filters", "radiometric_calibration", "codec"},
            path + ": simulate");
  if (YAML::Node v = s["codec"]) {
    if (v.IsScalar() && v.as<std::string>() == "none") {
      c.codec_enabled = false;
    } else {
      if (!v.IsMap()) Fail(path, "simulate.codec", "must be 'none' or a map");
      CheckKeys(v, {"codec", "crf", "preset", "pixel_format"}, path + ": simulate.codec");
      c.codec_enabled = true;
      Read(v, "codec", &c.codec.codec, path, "simulate.codec.");
      Read(v, "crf", &c.codec.crf, path, "simulate.codec.");
      Read(v, "preset", &c.codec.preset, path, "simulate.codec.");
      Read(v, "pixel_format", &c.codec.pixel_format, path, "simulate.codec.");
    }
  }
  if (YAML::Node r = s["radiometry"])
    c.radiometry = CameraRadiometry::FromYaml(r, fs::path(path).parent_path().string(),
                                              path + ": simulate.radiometry");
  if (YAML::Node g = s["camera_gains"]) {
    if (!g.IsSequence()) Fail(path, "simulate.camera_gains", "a list of [r, g, b], one per camera");
    for (std::size_t i = 0; i < g.size(); ++i)
      c.camera_gains.push_back(
          ReadVec3(g[i], path, "simulate.camera_gains[" + std::to_string(i) + "]"));
  }
  if (YAML::Node f = s["camera_filters"]) {
    if (!f.IsSequence())
      Fail(path, "simulate.camera_filters", "a list of [centre_nm, fwhm_nm], one per camera");
    for (std::size_t i = 0; i < f.size(); ++i) {
      const std::string where = "simulate.camera_filters[" + std::to_string(i) + "]";
      if (!f[i].IsSequence() || f[i].size() != 2) Fail(path, where, "[centre_nm, fwhm_nm]");
      SpectralBand band;
      try {
        band.centre_nm = f[i][0].as<double>();
        band.fwhm_nm = f[i][1].as<double>();
      } catch (const YAML::Exception&) {
        Fail(path, where, "two numbers, [centre_nm, fwhm_nm]");
      }
      c.camera_filters.push_back(band);
    }
  }
  if (YAML::Node r = s["radiometric_calibration"]) {
    CheckKeys(r, {"enabled", "temperatures_k", "levels", "emissivity"},
              path + ": simulate.radiometric_calibration");
    auto& rc = c.radiometric_calibration;
    Read(r, "enabled", &rc.enabled, path, "simulate.radiometric_calibration.");
    Read(r, "emissivity", &rc.emissivity, path, "simulate.radiometric_calibration.");
    if (r["temperatures_k"]) rc.temperatures_k = r["temperatures_k"].as<std::vector<double>>();
    if (r["levels"]) rc.levels = r["levels"].as<std::vector<double>>();
  }
  Read(s, "seed", &c.seed, path, "simulate.");
  Read(s, "frames", &c.frames, path, "simulate.");
  Read(s, "frame_rate_hz", &c.frame_rate_hz, path, "simulate.");
  Read(s, "absorption", &c.absorption, path, "simulate.");
  Read(s, "grid_resolution", &c.grid_resolution, path, "simulate.");
  Read(s, "noise_dn", &c.noise_dn, path, "simulate.");
  if (YAML::Node e = s["exposure"]) {
    std::string text = e.as<std::string>();
    if (text == "auto") {
      c.auto_exposure = true;
    } else {
      c.auto_exposure = false;
      Read(s, "exposure", &c.exposure, path, "simulate.");
    }
  }
  if (YAML::Node f = s["fire"]) {
    CheckKeys(f,
              {"kind", "peak_temperature_k", "ambient_temperature_k", "peak_soot_volume_fraction",
               "licks", "supersample"},
              path + ": simulate.fire");
    std::string kind = "candle";
    Read(f, "kind", &kind, path, "simulate.fire.");
    try {
      c.fire.kind = synthetic::FireKindFromName(kind);
    } catch (const InputError& e) {
      Fail(path, "simulate.fire.kind", e.what());
    }
    Read(f, "peak_temperature_k", &c.fire.peak_temperature_k, path, "simulate.fire.");
    Read(f, "ambient_temperature_k", &c.fire.ambient_temperature_k, path, "simulate.fire.");
    Read(f, "peak_soot_volume_fraction", &c.fire.peak_soot_volume_fraction, path, "simulate.fire.");
    Read(f, "licks", &c.fire.licks, path, "simulate.fire.");
    Read(f, "supersample", &c.fire.supersample, path, "simulate.fire.");
  }
  if (YAML::Node b = s["box"]) {
    CheckKeys(b, {"min", "max"}, path + ": simulate.box");
    if (!b["min"] || !b["max"]) Fail(path, "simulate.box", "needs min and max");
    c.box.min_in_rig = ReadVec3(b["min"], path, "simulate.box.min");
    c.box.max_in_rig = ReadVec3(b["max"], path, "simulate.box.max");
  }
  if (YAML::Node r = s["rig"]) {
    CheckKeys(r,
              {"cameras", "azimuths_deg", "distance_m", "elevation_deg", "width", "height", "fill",
               "lensmodel", "distortion"},
              path + ": simulate.rig");
    Read(r, "cameras", &c.ring.cameras, path, "simulate.rig.");
    Read(r, "azimuths_deg", &c.ring.azimuths_deg, path, "simulate.rig.");
    Read(r, "distance_m", &c.ring.distance_m, path, "simulate.rig.");
    Read(r, "elevation_deg", &c.ring.elevation_deg, path, "simulate.rig.");
    Read(r, "width", &c.ring.width, path, "simulate.rig.");
    Read(r, "height", &c.ring.height, path, "simulate.rig.");
    Read(r, "fill", &c.ring.fill, path, "simulate.rig.");
    Read(r, "lensmodel", &c.ring.lensmodel, path, "simulate.rig.");
    Read(r, "distortion", &c.ring.distortion, path, "simulate.rig.");
  }
  if (YAML::Node cal = s["calibration"]) {
    CheckKeys(cal,
              {"enabled", "board", "squares", "square_m", "marker_m", "shared_per_pair",
               "closeups_per_camera", "shadow", "gradient", "blur_px"},
              path + ": simulate.calibration");
    Read(cal, "enabled", &c.calibration, path, "simulate.calibration.");
    std::string board = "charuco";
    Read(cal, "board", &board, path, "simulate.calibration.");
    if (board == "charuco")
      c.board.type = synthetic::BoardType::kCharuco;
    else if (board == "chessboard")
      c.board.type = synthetic::BoardType::kChessboard;
    else
      Fail(path, "simulate.calibration.board", "must be 'charuco' or 'chessboard'");
    if (YAML::Node sq = cal["squares"]) {
      if (!sq.IsSequence() || sq.size() != 2)
        Fail(path, "simulate.calibration.squares", "must be [x, y]");
      c.board.squares_x = sq[0].as<int>();
      c.board.squares_y = sq[1].as<int>();
    }
    Read(cal, "square_m", &c.board.square_m, path, "simulate.calibration.");
    Read(cal, "marker_m", &c.board.marker_m, path, "simulate.calibration.");
    Read(cal, "shared_per_pair", &c.shared_per_pair, path, "simulate.calibration.");
    Read(cal, "closeups_per_camera", &c.closeups_per_camera, path, "simulate.calibration.");
    Read(cal, "shadow", &c.board_lighting.shadow, path, "simulate.calibration.");
    Read(cal, "gradient", &c.board_lighting.gradient, path, "simulate.calibration.");
    Read(cal, "blur_px", &c.board_lighting.blur_px, path, "simulate.calibration.");
    try {
      c.board_lighting.Validate();
    } catch (const InputError& e) {
      Fail(path, "simulate.calibration", e.what());
    }
  }
  if (YAML::Node r = s["render"]) {
    CheckKeys(r, {"step_voxels", "pixel_samples"}, path + ": simulate.render");
    Read(r, "step_voxels", &c.render.step_voxels, path, "simulate.render.");
    Read(r, "pixel_samples", &c.pixel_samples, path, "simulate.render.");
  }
}

}  // namespace

SimulateConfig SimulateConfig::Load(const std::string& path) {
  const YAML::Node root = LoadYamlFile(path, "config file");
  YAML::Node s = root.IsMap() ? root["simulate"] : YAML::Node();
  if (!s || !s.IsMap())
    Fail(path, "simulate", "missing; a simulation config has a top-level 'simulate' map");
  SimulateConfig c;
  try {
    ReadMaps(s, path, &c);
  } catch (const YAML::Exception& e) {  // a value of the wrong shape deeper down
    throw InputError(path + ": " + e.what());
  } catch (const InputError& e) {  // CheckKeys: an unknown key, or not a map
    throw InputError(e.what());
  }
  try {
    c.Validate();
  } catch (const InputError& e) {
    throw InputError(path + ": " + e.what());
  }
  return c;
}

void SimulateConfig::Validate() const {
  auto fail = [](const std::string& what) { throw InputError("simulate." + what); };
  if (frames < 1 || frames > 100000) fail("frames must be in [1, 100000]");
  if (!(frame_rate_hz > 0) || !(frame_rate_hz <= 100000))
    fail("frame_rate_hz must be in (0, 100000]");
  if (absorption != "soot" && absorption != "grey") fail("absorption must be 'soot' or 'grey'");
  if (grid_resolution < 1 || grid_resolution > 1024) fail("grid_resolution must be in [1, 1024]");
  if (!auto_exposure && (!(exposure >= 0.01) || !(exposure <= 1000)))
    fail("exposure must be 'auto' or in [0.01, 1000]");
  if (!(noise_dn >= 0) || !(noise_dn <= 50)) fail("noise_dn must be in [0, 50]");
  if (codec_enabled) {
    try {
      codec.Validate();
    } catch (const InputError& e) {
      fail(std::string("codec: ") + e.what());
    }
    if (radiometry.bit_depth > 8)
      fail("codec: a video codec records 8-bit frames; the radiometry has " +
           std::to_string(radiometry.bit_depth) + " bits");
  }
  if (pixel_samples < 1 || pixel_samples > 8) fail("render.pixel_samples must be in [1, 8]");
  if (!box.IsValid()) fail("box: max must exceed min on every axis");
  if (shared_per_pair < 0 || closeups_per_camera < 0) fail("calibration view counts must be >= 0");
  if (!camera_gains.empty() && int(camera_gains.size()) != ring.cameras)
    fail("camera_gains: one [r, g, b] per camera (" + std::to_string(ring.cameras) + "), got " +
         std::to_string(camera_gains.size()));
  for (const Eigen::Vector3d& g : camera_gains)
    if (!(g.minCoeff() > 0) || !g.allFinite()) fail("camera_gains: every gain must be > 0");
  if (!camera_filters.empty() && int(camera_filters.size()) != ring.cameras)
    fail("camera_filters: one [centre_nm, fwhm_nm] per camera (" + std::to_string(ring.cameras) +
         "), got " + std::to_string(camera_filters.size()));
  for (std::size_t c = 0; c < camera_filters.size(); ++c) {
    const SpectralBand& b = camera_filters[c];
    const bool none = b.fwhm_nm == 0;  // [0, 0] (or any centre with no width): no filter
    if (!std::isfinite(b.centre_nm + b.fwhm_nm) || !(b.fwhm_nm >= 0) ||
        (!none && !(b.centre_nm > 0)))
      fail("camera_filters[" + std::to_string(c) +
           "]: a centre > 0 nm and a width > 0 nm, or [0, 0] for none");
  }
  radiometry.Validate("simulate");
  // Every camera as it will be filmed, checked before anything is written: the rig's reader
  // refuses what its Validate refuses (a filter at 100 nm), and a filter where the sensor sees
  // nothing (5000 nm) left a half-written dataset that a second run would not overwrite.
  if (!camera_filters.empty() || !camera_gains.empty())
    for (int c = 0; c < ring.cameras; ++c) {
      const std::string where =
          "simulate: camera " + std::to_string(c) +
          (c < int(camera_filters.size()) ? " (camera_filters[" + std::to_string(c) + "])"
                                          : std::string());
      const CameraRadiometry film = CameraFilm(std::size_t(c));
      film.Validate(where);
      // Without its gains, as the renderers below take it: the same cached response, built once.
      CameraRadiometry spectral = radiometry;
      spectral.spectral = film.spectral;
      try {
        ChannelResponse::ForCamera(spectral);
      } catch (const InputError& e) {
        throw InputError(where + ": " + e.what());
      }
    }
  if (radiometric_calibration.enabled) {
    const auto& rc = radiometric_calibration;
    if (rc.temperatures_k.empty() || rc.levels.empty())
      fail("radiometric_calibration: needs temperatures_k and levels");
    for (double t : rc.temperatures_k)
      if (!(t >= 500 && t <= 4000)) fail("radiometric_calibration.temperatures_k: in 500..4000 K");
    for (double l : rc.levels)
      if (!(l > 0 && l <= 10)) fail("radiometric_calibration.levels: in (0, 10]");
    if (!(rc.emissivity > 0 && rc.emissivity <= 1))
      fail("radiometric_calibration.emissivity: in (0, 1]");
  }
  fire.Validate();
  ring.Validate();
  board.Validate();
  render.Validate();
}

CameraRadiometry SimulateConfig::CameraFilm(std::size_t c) const {
  CameraRadiometry film = radiometry;
  if (c < camera_gains.size()) film.gain = film.gain.cwiseProduct(camera_gains[c]);
  if (c < camera_filters.size()) film.spectral.filter = camera_filters[c];
  return film;
}

double SimExposureUnitUs(double exposure) { return CameraSettings{}.exposure_us / exposure; }

double AutoExposure(const std::vector<ImageF>& linear) {
  std::vector<float> values;
  float max_value = 0;
  for (const auto& img : linear)
    for (std::size_t p = 0; p < img.num_pixels(); ++p) {
      const float m = std::max({img.pixels[3 * p], img.pixels[3 * p + 1], img.pixels[3 * p + 2]});
      max_value = std::max(max_value, m);
      values.push_back(m);
    }
  std::vector<float> fire_values;
  for (float v : values)
    if (v > 1e-3f * max_value && v > 0) fire_values.push_back(v);
  if (fire_values.empty()) return 0;
  const std::size_t idx = static_cast<std::size_t>(0.995 * (fire_values.size() - 1));
  std::nth_element(fire_values.begin(), fire_values.begin() + idx, fire_values.end());
  return 1.0 / fire_values[idx];
}

int RecordCameraImage(const ImageF& linear, double exposure, const CameraRadiometry& radiometry,
                      double noise_dn, std::uint64_t seed, ImageU8* u8, ImageU16* u16) {
  if (radiometry.is_default()) {
    *u8 = ApplyCameraResponse(linear, exposure);
    AddSensorNoise(u8, noise_dn, seed);
    return 8;
  }
  if (!(exposure > 0) || !std::isfinite(exposure))
    throw InputError("exposure = " + std::to_string(exposure) + " must be finite and > 0");
  if (linear.channels != 3) throw InputError("a render has 3 channels");
  const int bits = radiometry.bit_depth > 8 ? 16 : 8;
  const CameraRadiometry::Decoding d = radiometry.DecodingFor(bits);
  const int channels = radiometry.channels();
  const double sigma = noise_dn * d.max_code / 255.0;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  const std::size_t n = linear.num_pixels();
  std::vector<double> codes(n * channels);
  for (std::size_t p = 0; p < n; ++p)
    for (int c = 0; c < channels; ++c) {
      double code = radiometry.Code(exposure * double(linear.pixels[3 * p + c]), d);
      if (sigma > 0) code = std::clamp(std::round(code + sigma * noise(rng)), 0.0, d.max_code);
      codes[p * channels + c] = code;
    }
  if (bits == 8) {
    *u8 = ImageU8(linear.width, linear.height, channels);
    for (std::size_t i = 0; i < codes.size(); ++i)
      u8->pixels[i] = static_cast<std::uint8_t>(codes[i]);
  } else {
    *u16 = ImageU16(linear.width, linear.height, channels);
    for (std::size_t i = 0; i < codes.size(); ++i)
      u16->pixels[i] = static_cast<std::uint16_t>(codes[i]);
  }
  return bits;
}

namespace {

// See Simulate in the header: an earlier simulation's own folders go, anything else stays.
void ClearEarlierSimulation(const std::string& out_dir) {
  static const char* const kOwned[] = {"frames", "truth", "calibration", "radiometry", "cameras"};
  std::vector<fs::path> present;
  for (const char* name : kOwned)
    if (fs::exists(fs::path(out_dir) / name)) present.push_back(fs::path(out_dir) / name);
  if (present.empty()) return;
  const fs::path dataset = fs::path(out_dir) / "dataset.yaml";
  bool simulated = false;
  try {
    const YAML::Node root = YAML::LoadFile(dataset.string());
    simulated = root["dataset"] && root["dataset"]["generator"] &&
                root["dataset"]["generator"].as<std::string>() == "flamerig simulate";
  } catch (const YAML::Exception&) {
    simulated = false;  // none, or not one simulate wrote
  }
  if (!simulated)
    throw InputError("simulate: " + out_dir + " holds " + present.front().filename().string() +
                     "/ but no dataset.yaml written by flamerig simulate (an exported recording?):"
                     " give a new or empty folder, so that nothing in it is overwritten");
  for (const fs::path& p : present) fs::remove_all(p);
}

}  // namespace

SimulateSummary Simulate(const SimulateConfig& config, const std::string& out_dir,
                         const ProgressCallback& progress) {
  config.Validate();
  const auto start = std::chrono::steady_clock::now();
  auto report = [&](const std::string& stage, int done, int total) {
    Progress p;
    p.stage = stage;
    p.unit = "frames";
    p.done = done;
    p.total = total;
    if (ReportProgress(progress, p)) throw Cancelled("simulate: cancelled");
  };
  Rig rig = synthetic::MakeRingRig(config.box, config.ring, "sim");
  for (std::size_t c = 0; c < rig.cameras.size(); ++c)
    rig.cameras[c].radiometry = config.CameraFilm(c);

  const AbsorptionModel absorption = AbsorptionModel::FromName(config.absorption);
  const GridGeometry grid = GridGeometry::FromBox(config.box, config.grid_resolution);
  // One renderer per distinct spectral response: a camera behind its own filter
  // (camera_filters) sees its own spectrum; cameras sharing a filter share a renderer. A camera's
  // own gains still multiply the output below.
  std::vector<std::unique_ptr<FireRenderer>> renderers;
  std::vector<std::size_t> renderer_of(rig.cameras.size(), 0);
  {
    std::vector<const ChannelResponse*> seen;
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      CameraRadiometry spectral = config.radiometry;
      if (c < config.camera_filters.size()) spectral.spectral.filter = config.camera_filters[c];
      RenderOptions own = config.render;
      own.response = ChannelResponse::ForCamera(spectral);
      const auto at = std::find(seen.begin(), seen.end(), own.response.get());
      renderer_of[c] = static_cast<std::size_t>(at - seen.begin());
      if (at == seen.end()) {
        seen.push_back(own.response.get());
        renderers.push_back(std::make_unique<FireRenderer>(absorption, own));
      }
    }
  }
  // Nothing is written before the renderers stand: a camera they refuse leaves no half dataset.
  ClearEarlierSimulation(out_dir);
  fs::create_directories(out_dir);
  SimulateSummary summary;
  summary.out_dir = out_dir;
  rig.Save((fs::path(out_dir) / "rig.yaml").string());
  summary.cameras = static_cast<int>(rig.cameras.size());
  std::vector<CameraRays> rays;  // through the pixels' centres (pixel_samples 1)
  if (config.pixel_samples == 1)
    for (const auto& c : rig.cameras) rays.emplace_back(c.model);

  YAML::Emitter yaml;
  yaml << YAML::BeginMap;
  yaml << YAML::Key << "dataset" << YAML::Value << YAML::BeginMap;
  yaml << YAML::Key << "generator" << YAML::Value << "flamerig simulate";
  yaml << YAML::Key << "rig" << YAML::Value << "rig.yaml";
  yaml << YAML::Key << "seed" << YAML::Value << config.seed;
  yaml << YAML::Key << "fire" << YAML::Value << synthetic::ToString(config.fire.kind);
  yaml << YAML::Key << "absorption" << YAML::Value << absorption.name();
  yaml << YAML::Key << "grid_dims" << YAML::Value << YAML::Flow
       << std::vector<int>{grid.dims.x(), grid.dims.y(), grid.dims.z()};
  yaml << YAML::Key << "voxel_size_m" << YAML::Value << grid.voxel_size_m.x();
  yaml << YAML::Key << "frame_rate_hz" << YAML::Value << config.frame_rate_hz;
  yaml << YAML::Key << "noise_dn" << YAML::Value << config.noise_dn;
  yaml << YAML::Key << "codec" << YAML::Value
       << (config.codec_enabled ? config.codec.Describe() + ", each frame intra-coded" : "none");
  yaml << YAML::Key << "render_step_voxels" << YAML::Value << config.render.step_voxels;
  yaml << YAML::Key << "pixel_samples" << YAML::Value << config.pixel_samples;

  double exposure = config.exposure;
  yaml << YAML::Key << "frames" << YAML::Value << YAML::BeginSeq;
  std::vector<ImageU8> preview, board_preview;  // frame 0 and the first board view, per camera
  for (int f = 0; f < config.frames; ++f) {
    report("fire frames", f, config.frames);
    synthetic::FireOptions fire_options = config.fire;
    fire_options.seed = config.seed;
    fire_options.time_s = f / config.frame_rate_hz;
    FireVolume fire = synthetic::MakeFire(grid, fire_options, absorption);
    fire.emission_rgb = synthetic::ThinEmissionRgb(fire, absorption);
    for (auto& r : renderers) r->SetVolume(grid, fire.temperature_k, fire.density_per_m3);
    std::vector<ImageF> linear(rig.cameras.size());
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const FireRenderer& renderer = *renderers[renderer_of[c]];
      // The centres' rays are kept across frames; pixel areas' rays are made per frame.
      summary.last_render =
          config.pixel_samples == 1
              ? renderer.Render(rays[c], &linear[c])
              : renderer.RenderPixelArea(rig.cameras[c].model, config.pixel_samples, &linear[c]);
      // A camera's own gains scale its output channels (camera_response.h).
      if (c < config.camera_gains.size())
        for (std::size_t p = 0; p < linear[c].num_pixels(); ++p)
          for (int k = 0; k < 3; ++k)
            linear[c].pixels[3 * p + k] *= float(config.camera_gains[c][k]);
    }

    if (f == 0 && config.auto_exposure) {
      const double automatic = AutoExposure(linear);
      if (!(automatic > 0)) {
        exposure = 1.0;
        summary.exposure_source = "auto: no fire visible, exposure 1";
      } else {
        exposure = std::clamp(automatic, 0.01, 1000.0);
        summary.exposure_source = "auto: 99.5th percentile of fire pixels at full scale";
      }
    } else if (f == 0) {
      summary.exposure_source = "config";
    }
    fire.metadata_numbers["exposure"] = exposure;
    const std::string name = FrameName(f);
    fs::create_directories(fs::path(out_dir) / "truth");
    WriteVdb((fs::path(out_dir) / "truth" / (name + ".vdb")).string(), fire);
    fs::path frame_dir = fs::path(out_dir) / "frames" / name;
    fs::create_directories(frame_dir);
    std::size_t saturated = 0, lit = 0;
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      if (f == 0) {
        const ImageU8 clean = ApplyCameraResponse(linear[c], exposure);
        for (std::size_t p = 0; p < clean.num_pixels(); ++p) {
          int m = std::max({clean.pixels[3 * p], clean.pixels[3 * p + 1], clean.pixels[3 * p + 2]});
          if (m > 2) ++lit;
          if (m == 255) ++saturated;
        }
      }
      ImageU8 u8;
      ImageU16 u16;
      const CameraRadiometry film = config.CameraFilm(c);
      const int bits = RecordCameraImage(linear[c], exposure, film, config.noise_dn,
                                         config.seed * 1000003ULL + f * 101ULL + c, &u8, &u16);
      if (config.codec_enabled && bits == 8) u8 = ThroughCodec(u8, config.codec);
      const std::string file = (frame_dir / (rig.cameras[c].name + ".png")).string();
      if (bits == 16)
        WritePng16(file, u16);
      else
        WritePng(file, u8);
      if (f == 0) {
        // The picture a person sees of it, as every reader of frames makes it.
        ImageU8 picture;
        LinearFrame unused;
        ImageF signal;
        DecodeCameraImage(u8, u16, bits, exposure, film, &picture, &unused, &signal);
        preview.push_back(std::move(picture));
      }
    }
    if (f == 0) summary.saturated_pixel_fraction = lit ? double(saturated) / lit : 0.0;
    yaml << YAML::BeginMap << YAML::Key << "name" << YAML::Value << name << YAML::Key << "time_s"
         << YAML::Value << fire_options.time_s << YAML::Key << "truth" << YAML::Value
         << "truth/" + name + ".vdb" << YAML::Key << "images" << YAML::Value << "frames/" + name
         << YAML::EndMap;
  }
  report("fire frames", config.frames, config.frames);
  yaml << YAML::EndSeq;
  yaml << YAML::Key << "exposure" << YAML::Value << exposure;
  yaml << YAML::Key << "exposure_source" << YAML::Value << summary.exposure_source;
  const double unit_us = SimExposureUnitUs(exposure);
  yaml << YAML::Key << "exposure_unit_us" << YAML::Value << unit_us;
  summary.exposure = exposure;
  summary.frames = config.frames;

  if (config.calibration) {
    auto written = synthetic::WriteCalibrationViews(
        rig, config.board, config.seed, config.shared_per_pair, config.closeups_per_camera,
        config.noise_dn, (fs::path(out_dir) / "calibration").string(), progress,
        config.board_lighting);
    for (auto& image : written.first_view) board_preview.push_back(std::move(image));
    summary.calibration_views = written.views;
    summary.calibration_images = written.images;
    yaml << YAML::Key << "calibration" << YAML::Value << "calibration/board.yaml";
  }
  if (config.radiometric_calibration.enabled) {
    const auto& rc = config.radiometric_calibration;
    RadiometricShots shots;
    shots.emissivity = rc.emissivity;
    shots.exposure_unit_us = unit_us;
    const fs::path dir = fs::path(out_dir) / "radiometry";
    fs::create_directories(dir);
    const int total = int(rig.cameras.size() * rc.temperatures_k.size() * rc.levels.size());
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const CameraRadiometry film = config.CameraFilm(c);
      const auto response = ChannelResponse::ForCamera(film);
      for (std::size_t t = 0; t < rc.temperatures_k.size(); ++t) {
        const double peak =
            rc.emissivity *
            response->Blackbody(rc.temperatures_k[t]).head(film.channels()).maxCoeff();
        for (std::size_t l = 0; l < rc.levels.size(); ++l) {
          report("radiometric calibration", int(shots.shots.size()), total);
          RadiometricShot shot;
          shot.camera = rig.cameras[c].name;
          shot.temperature_k = rc.temperatures_k[t];
          // As the camera takes it: an exposure time at 0 dB, in whole microseconds where
          // that moves it by 1% at most.
          const double us = rc.levels[l] / peak * unit_us;
          shot.exposure_us = us >= 100 ? std::round(us) : us;
          shot.exposure = shot.exposure_us / unit_us;
          char name[96];
          std::snprintf(name, sizeof(name), "%s_%.0fK_%zu.png", shot.camera.c_str(),
                        shot.temperature_k, l);
          shot.image = (dir / name).string();
          ImageU8 u8;
          ImageU16 u16;
          const int bits = FilmCalibrationSource(
              rig.cameras[c].model.width(), rig.cameras[c].model.height(), shot.temperature_k,
              rc.emissivity, shot.exposure, film, config.noise_dn,
              config.seed * 7919ULL + c * 1009ULL + t * 101ULL + l, &u8, &u16);
          if (bits == 16)
            WritePng16(shot.image, u16);
          else
            WritePng(shot.image, u8);
          shots.shots.push_back(shot);
        }
      }
    }
    shots.Save((dir / "shots.yaml").string());
    summary.radiometric_shots = int(shots.shots.size());
    report("radiometric calibration", total, total);
    yaml << YAML::Key << "radiometric_calibration" << YAML::Value << "radiometry/shots.yaml";
  }
  yaml << YAML::EndMap << YAML::EndMap;
  WriteFileAtomically((fs::path(out_dir) / "dataset.yaml").string(),
                      std::string(yaml.c_str()) + "\n");
  if (!preview.empty()) {
    PictureGrid grid;
    grid.title = "simulated dataset: " + std::to_string(rig.cameras.size()) + " cameras";
    for (const auto& camera : rig.cameras) grid.column_labels.push_back(camera.name);
    grid.row_labels.push_back("fire, frame 0");
    grid.rows.push_back(std::move(preview));
    if (!board_preview.empty()) {
      grid.row_labels.push_back("calibration board, first view");
      grid.rows.push_back(std::move(board_preview));
    }
    grid.tile_height = rig.cameras.size() > 4 ? 160 : 240;
    WritePng((fs::path(out_dir) / "preview.png").string(), DrawPictureGrid(grid));
  }
  summary.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace flamerig
