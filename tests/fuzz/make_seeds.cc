// Writes the seed corpora of the fuzz targets into tests/fuzz/corpus/<target>/ (checked in; run
// again only when a format changes): `build/tests/fuzz_make_seeds tests/fuzz/corpus`. Each seed is a
// small valid input written by flamerig's own writers, so the fuzzers start from the formats'
// structure.
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include "acquisition/recording.h"
#include "calibration/board.h"
#include "calibration/camera_model.h"
#include "core/image.h"
#include "tests/fuzz/small_fire.h"
#include "tomography/vdb_io.h"

namespace fs = std::filesystem;
using namespace flamerig;

namespace {

void Write(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << text;
}

std::string Slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: fuzz_make_seeds CORPUS_DIR\n";
    return 2;
  }
  const fs::path out(argv[1]);
  const fs::path tmp = fs::temp_directory_path() / "flamerig_fuzz_seeds";
  fs::remove_all(tmp);
  fs::create_directories(tmp);

  // capture_config
  Write(out / "capture_config" / "sim.yaml",
        "data_dir: recordings\nsync: hardware-trigger\ntrigger_rate_hz: 30\nset_timeout_ms: 200\n"
        "buffers: 8\npretrigger_seconds: 2\nqueue_mb: 512\ncameras:\n"
        "  - {name: cam0, driver: sim, id: SIM0, width: 64, height: 48, pixel_format: Mono8,\n"
        "     sim: {jitter_us: 50, drop_probability: 0.01}}\n"
        "  - {name: cam1, driver: sim, id: SIM1, width: 64, height: 48, pixel_format: BayerRG8}\n");
  Write(out / "capture_config" / "ptp.yaml",
        "sync: ptp\ntrigger_rate_hz: 100\naction: {device_key: 0x10, group_key: 1, group_mask: "
        "0xffffffff, lead_ms: 20, destination: 127.0.0.1, port: 3956}\ncameras:\n"
        "  - {name: a, driver: aravis, id: 127.0.0.2, width: 640, height: 480}\n");

  // cameramodel and rig
  const CameraModel model("LENSMODEL_OPENCV8",
                          {500, 505, 159.5, 119.5, 0.01, -0.02, 0.001, 0.0005, 0.001, 0, 0, 0},
                          Rigid3(), 320, 240);
  model.Save((tmp / "cam.cameramodel").string());
  Write(out / "cameramodel" / "opencv8.cameramodel", Slurp(tmp / "cam.cameramodel"));
  const CameraModel pinhole("LENSMODEL_PINHOLE", {500, 500, 319.5, 239.5}, Rigid3(), 640, 480);
  pinhole.Save((tmp / "pin.cameramodel").string());
  Write(out / "cameramodel" / "pinhole.cameramodel", Slurp(tmp / "pin.cameramodel"));
  Write(out / "rig" / "rig.yaml",
        "rig:\n  name: fuzz\n  up: [0, 1, 0]\n  box:\n    min: [-0.05, 0.0, -0.05]\n"
        "    max: [0.05, 0.15, 0.05]\n  cameras:\n    - name: cam0\n"
        "      model: cameras/cam0.cameramodel\n");

  // vdb
  FireVolume v = flamerig_fuzz::SmallFire(Eigen::Vector3i(3, 4, 2), 5);
  v.emission_rgb.assign(3 * v.geometry.num_voxels(), 0.0f);
  v.emission_rgb[16] = 2.5f;
  v.metadata_numbers["exposure"] = 1.5;
  v.metadata_text["absorption_model"] = "soot";
  WriteVdb((tmp / "v.vdb").string(), v);
  Write(out / "vdb" / "small.vdb", Slurp(tmp / "v.vdb"));
  // A fitted soot volume's extra grids: the volume fraction and a sigma (two grids only: the seed
  // must stay under scripts/fuzz.sh's -max_len of 64 KiB, or libFuzzer cuts it).
  v.soot_volume_fraction.assign(v.geometry.num_voxels(), 0.0f);
  v.soot_volume_fraction[5] = 1e-6f;
  v.temperature_sigma_k.assign(v.geometry.num_voxels(), 50.0f);
  v.metadata_numbers["soot_volume_fraction_peak"] = 1e-6;
  WriteVdb((tmp / "fitted.vdb").string(), v);
  Write(out / "vdb" / "fitted.vdb", Slurp(tmp / "fitted.vdb"));

  // simulate_config: the shapes of config/sim_rig.yaml and config/sim_licks.yaml, small
  Write(out / "simulate_config" / "ring.yaml",
        "simulate:\n  seed: 3\n  frames: 2\n  fire: {kind: licks, peak_temperature_k: 2100, "
        "peak_soot_volume_fraction: 2.0e-6}\n  absorption: soot\n  grid_resolution: 16\n"
        "  box: {min: [-0.05, 0.0, -0.05], max: [0.05, 0.14, 0.05]}\n"
        "  rig: {cameras: 3, distance_m: 0.5, elevation_deg: 10, width: 64, height: 48}\n"
        "  calibration: {enabled: true, board: charuco, squares: [7, 5], square_m: 0.015, "
        "marker_m: 0.011}\n");
  Write(out / "simulate_config" / "plain.yaml",
        "simulate:\n  frames: 1\n  grid_resolution: 8\n  calibration: {enabled: false}\n");

  // scene: the shape of config/scene_candle.yaml, with the fuzz target's fire.vdb and mesh.obj
  Write(out / "scene" / "candle.yaml",
        "scene:\n  camera: {position: [0.0, 0.09, 0.34], look_at: [0.0, 0.03, 0.0], fov_deg: 35, "
        "width: 96, height: 54}\n  background: [0, 0, 0]\n  materials:\n"
        "    table: {albedo: [0.55, 0.45, 0.35]}\n"
        "    pewter: {albedo: [0.15, 0.15, 0.15], specular: [0.5, 0.5, 0.5], shininess: 300}\n"
        "  objects:\n"
        "    - {type: plane, centre: [0, 0, 0], normal: [0, 1, 0], size: [0.6, 0.6], material: "
        "table}\n"
        "    - {type: sphere, centre: [0.045, 0.02, 0.03], radius: 0.02, material: pewter}\n"
        "    - {type: box, min: [-0.075, 0.0, -0.03], max: [-0.045, 0.045, 0.0], material: "
        "table}\n"
        "    - {type: mesh, file: mesh.obj, scale: 2, rotate_y_deg: 30, translate: [0, 0, 0], "
        "material: pewter}\n"
        "  fires:\n    - {volume: fire.vdb, absorption: soot, scale: 1, translate: [0, 0, 0]}\n"
        "render: {samples: 4, samples_per_pass: 2, seed: 1, lighting: compare}\n"
        "display: {exposure: 1, key: 0.18, white: 0}\n");

  // streampix: version 5 (images from byte 8192), 2 frames of 4x3 mono 8-bit.
  {
    std::string h(8192, '\0');
    auto put32 = [&](std::size_t at, std::uint32_t x) { std::memcpy(&h[at], &x, 4); };
    put32(0, 0xFEED);
    put32(28, 5);
    put32(32, 1024);
    put32(548, 4);
    put32(552, 3);
    put32(556, 8);
    put32(560, 8);
    put32(564, 12);
    put32(568, 100);
    put32(572, 2);
    put32(580, 24);
    const double fps = 30;
    std::memcpy(&h[584], &fps, 8);
    std::string frames;
    for (int f = 0; f < 2; ++f) {
      std::string block(24, '\0');
      for (int i = 0; i < 12; ++i) block[i] = static_cast<char>(20 * f + i);
      const std::int32_t sec = 1600000000 + f;
      std::memcpy(&block[12], &sec, 4);
      frames += block;
    }
    Write(out / "streampix" / "v5.seq", h + frames);
  }

  // image: small PNGs as cameras and `simulate` write them: 8-bit RGB and grey, 16-bit grey.
  {
    ImageU8 rgb(6, 4, 3), grey(5, 3, 1);
    ImageU16 deep(4, 3, 1);
    for (std::size_t i = 0; i < rgb.pixels.size(); ++i) rgb.pixels[i] = (i * 37) & 0xff;
    for (std::size_t i = 0; i < grey.pixels.size(); ++i) grey.pixels[i] = (i * 11) & 0xff;
    for (std::size_t i = 0; i < deep.pixels.size(); ++i) deep.pixels[i] = (i * 4099) & 0xffff;
    fs::create_directories(out / "image");
    WritePng((out / "image" / "rgb8.png").string(), rgb);
    WritePng((out / "image" / "grey8.png").string(), grey);
    WritePng16((out / "image" / "grey16.png").string(), deep);
  }

  // detection_cache (the default board: ChArUco 7x5, 24 inner corners)
  Write(out / "detection_cache" / "cache.txt",
        "# flamerig board detections v2\n"
        "board charuco 7x5 squares of 0.012 m, markers 0.009 m, dictionary 0\n"
        "detect " +
            flamerig::DetectOptions().Describe() +
            "\n"
            "0a1b2c3d_320x240 6 0 10.5 20.25 1 30.5 20.5 2 50 20 6 11 40 7 31 40 8 50 40\n"
            "0a1b2c3d_320x240 detector charuco\n"
            "0a1b2c3d_320x240 reject 3 69.5 20.5 6.1 px from where its 8 neighbours put it\n"
            "deadbeef_320x240 0 no board: blurred\n");

  // control
  int k = 0;
  for (const char* line : {"status", "cameras", "configure cam0 width 64", "preview cam0 2",
                           "start take1", "stop", "event ignition", "arm", "disarm"})
    Write(out / "control" / ("request_" + std::to_string(k++)), line);

  // recording: one camera, three sets (the second missing), as the target joins the files.
  {
    RecordingMetadata meta;
    meta.sync_mode = "software-trigger";
    RecordingCamera c;
    c.name = "cam0";
    c.description.driver = "sim";
    c.settings.width = 4;
    c.settings.height = 2;
    meta.cameras.push_back(c);
    const fs::path dir = tmp / "rec";
    {
      Recorder recorder(dir.string(), meta);
      for (int s = 0; s < 3; ++s) {
        FrameSet set;
        set.index = s;
        set.trigger_id = s;
        set.frames.resize(1);
        if (s != 1) {
          Frame f;
          f.info.frame_id = 10 + s;
          f.info.width = 4;
          f.info.height = 2;
          f.data = std::make_shared<std::vector<std::uint8_t>>(8, static_cast<std::uint8_t>(s));
          set.frames[0] = f;
        }
        recorder.Submit(set);
      }
      recorder.Close();
    }
    const std::string sep("\0FLAMERIG-FILE\0", 15);
    Write(out / "recording" / "three_sets",
          Slurp(dir / "metadata.yaml") + sep + Slurp(dir / "sets.index") + sep +
              Slurp(dir / "cam00.index") + sep + Slurp(dir / "cam00.data"));
  }
  fs::remove_all(tmp);
  std::cout << "seeds written to " << out << "\n";
  return 0;
}
