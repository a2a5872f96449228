#include "pipeline/frame_source.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include <yaml-cpp/yaml.h>

#include "acquisition/frame.h"
#include "acquisition/recording.h"
#include "acquisition/streampix.h"
#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/error.h"
#include "core/read_file.h"
#include "core/srgb.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

std::string SetName(std::size_t i) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%06zu", i);
  return name;
}

}  // namespace

void DecodeCameraImage(const ImageU8& u8, const ImageU16& u16, int bits, double exposure,
                       const CameraRadiometry& radiometry, ImageU8* image, LinearFrame* linear,
                       ImageF* signal) {
  if (!(exposure > 0) || !std::isfinite(exposure))
    throw InputError("exposure = " + std::to_string(exposure) + " must be finite and > 0");
  if (bits != 8 && bits != 16)
    throw InputError("frames are 8 or 16 bits, not " + std::to_string(bits));
  const int channels = bits == 16 ? u16.channels : u8.channels;
  const int width = bits == 16 ? u16.width : u8.width;
  const int height = bits == 16 ? u16.height : u8.height;
  if (channels != 1 && channels != 3)
    throw InputError("a frame has 1 or 3 channels, not " + std::to_string(channels));
  if (channels == 1 && radiometry.channels() == 3)
    throw InputError(
        "a one-channel (mono) frame from a camera the rig gives a colour response (" +
        radiometry.spectral.Describe() +
        "): a mono camera records no colour, so its temperature cannot be fitted as if it did; "
        "give the camera's spectral sensitivity in the rig (radiometry: spectral: table or "
        "bands, one channel)");
  if (channels == 3 && radiometry.channels() == 1)
    throw InputError("a colour frame from a camera the rig describes as mono (" +
                     radiometry.spectral.Describe() + ")");
  const CameraRadiometry::Decoding decoding = radiometry.DecodingFor(bits);
  const std::vector<float> table = radiometry.SignalTable(bits);
  const std::size_t n = static_cast<std::size_t>(width) * height;
  *signal = ImageF(width, height, 3);
  *image = ImageU8(width, height, 3);
  linear->radiance = ImageF(width, height, 3);
  linear->saturated.assign(n, 0);
  const double max_code = decoding.max_code;
  // The tomography's frames are in the camera's unit-gain channels, so that cameras of one kind
  // with different gains (white balance, sensor spread) agree on one emission.
  double unit[3];
  for (int c = 0; c < 3; ++c)
    unit[c] = 1.0 / (exposure * radiometry.gain[radiometry.channels() == 1 ? 0 : c]);
  linear->full_scale = std::max({unit[0], unit[1], unit[2]});
  // The first code above black, in radiance: the frame's quantisation step where the background
  // lies (the fire mask's noise floor, visual_hull.h).
  const std::size_t first_step = std::min<std::size_t>(
      table.size() - 1, static_cast<std::size_t>(std::floor(decoding.black)) + 1);
  linear->quantum = table[first_step] * linear->full_scale;
  // What a person sees: the frame itself when it is 8-bit sRGB, else the signal encoded.
  const bool picture_is_frame = bits == 8 && decoding.transfer == TransferFunction::kSrgb &&
                                decoding.black == 0 && decoding.saturation == 255;
  for (std::size_t p = 0; p < n; ++p) {
    for (int c = 0; c < 3; ++c) {
      const std::size_t k = p * channels + (channels == 1 ? 0 : c);
      const unsigned code = bits == 16 ? u16.pixels[k] : u8.pixels[k];
      if (code > max_code)
        throw InputError("pixel (" + std::to_string(p % width) + ", " + std::to_string(p / width) +
                         ") holds " + std::to_string(code) + ", above the " +
                         std::to_string(static_cast<int>(max_code)) + " of a " +
                         std::to_string(radiometry.bit_depth) +
                         "-bit camera (a wrong bit_depth in the rig, or a damaged frame)");
      const float v = table[code];
      signal->pixels[3 * p + c] = v;
      linear->radiance.pixels[3 * p + c] = static_cast<float>(v * unit[c]);
      if (code >= decoding.saturation) linear->saturated[p] = 1;
      image->pixels[3 * p + c] =
          picture_is_frame ? static_cast<std::uint8_t>(code) : QuantizeU8(SrgbEncode(v));
    }
  }
}

Rig WithInputTransfer(Rig rig, const std::string& spec) {
  if (spec.empty()) return rig;
  TransferFunction transfer = TransferFunction::kSrgb;
  double gamma = 2.2;
  ParseTransferSpec(spec, &transfer, &gamma);
  for (RigCamera& camera : rig.cameras) {
    camera.radiometry.transfer = transfer;
    camera.radiometry.gamma = gamma;
    camera.radiometry.curve.clear();
  }
  return rig;
}

void WriteExportedFormats(const std::string& dir, const std::vector<std::string>& cameras,
                          const std::vector<PixelFormat>& formats,
                          const std::vector<std::string>& wire_formats) {
  YAML::Emitter out;
  out << YAML::Comment(
      "The pixel format each camera recorded (flamerig export). A Bayer camera's PNGs here are "
      "its mosaic demosaiced (OpenCV's bilinear interpolation); fit and run with "
      "--images fit them through that mosaic.");
  out << YAML::BeginMap << YAML::Key << "cameras" << YAML::Value << YAML::BeginMap;
  for (std::size_t c = 0; c < cameras.size() && c < formats.size(); ++c)
    out << YAML::Key << cameras[c] << YAML::Value
        << (c < wire_formats.size() && !wire_formats[c].empty() ? wire_formats[c]
                                                                : ToString(formats[c]));
  out << YAML::EndMap << YAML::EndMap;
  WriteFileAtomically((fs::path(dir) / kExportedFormatsFile).string(),
                      std::string(out.c_str()) + "\n");
}

std::vector<ExportedFormat> ReadExportedFormats(const std::string& dir, const Rig& rig) {
  std::vector<ExportedFormat> out(rig.cameras.size());
  const fs::path path = fs::path(dir) / kExportedFormatsFile;
  if (!fs::exists(path)) return out;
  const std::string shape = ": needs a map 'cameras: {NAME: PIXEL_FORMAT, ...}'";
  try {
    const YAML::Node root = YAML::LoadFile(path.string());
    if (!root.IsMap() || !root["cameras"] || !root["cameras"].IsMap())
      throw InputError(path.string() + shape);
    for (const auto& entry : root["cameras"]) {
      if (!entry.first.IsScalar() || !entry.second.IsScalar())
        throw InputError(path.string() + shape);
      const std::string name = entry.first.as<std::string>();
      CameraSettings recorded;  // a stored format, or the wire format a camera sent
      try {
        recorded.SetPixelFormat(entry.second.as<std::string>());
      } catch (const Error& e) {
        throw InputError(path.string() + ": camera '" + name + "': " + e.what());
      }
      for (std::size_t c = 0; c < rig.cameras.size(); ++c)
        if (rig.cameras[c].name == name)
          out[c] = {BayerLayoutOf(recorded.pixel_format),
                    WireBitsOf(recorded.pixel_format, recorded.wire_format)};
    }
  } catch (const YAML::Exception& e) {
    throw InputError(path.string() + ": not YAML (" + e.what() + ")");
  }
  return out;
}

namespace {

// A folder of one frame set that an export wrote (frame_NNNNNN beside the export's sets.csv): its
// set number; else -1.
long long ExportedSetNumber(const fs::path& folder) {
  const std::string name = folder.filename().string();
  const bool set_folder =
      name.size() == 12 && name.rfind("frame_", 0) == 0 &&
      std::all_of(name.begin() + 6, name.end(), [](char ch) { return ch >= '0' && ch <= '9'; });
  if (!set_folder || !fs::exists(folder.parent_path() / "sets.csv")) return -1;
  return std::stoll(name.substr(6));
}

}  // namespace

void WriteExportedReference(const std::string& dir, const ExposureReference& reference) {
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  out << YAML::Comment(
      "The take's exposure reference (flamerig export): the recording's first camera's settings "
      "at its start. Through a rig that knows its exposure unit, exposure = exposure_us x "
      "10^(gain_db / 20, where gain_in_db) / the unit; sets.csv gives each camera's factor "
      "against it.");
  out << YAML::BeginMap << YAML::Key << "reference" << YAML::Value << YAML::Flow << YAML::BeginMap
      << YAML::Key << "camera" << YAML::Value << reference.camera << YAML::Key << "exposure_us"
      << YAML::Value << reference.exposure_us << YAML::Key << "gain_db" << YAML::Value
      << reference.gain_db << YAML::Key << "gain_in_db" << YAML::Value << reference.gain_in_db
      << YAML::EndMap << YAML::EndMap;
  WriteFileAtomically((fs::path(dir) / kExportedReferenceFile).string(),
                      std::string(out.c_str()) + "\n");
}

std::optional<ExposureReference> ReadExportedReference(const std::string& dir) {
  std::error_code ec;
  const fs::path folder = fs::weakly_canonical(dir, ec);
  if (ec) return std::nullopt;
  fs::path path = folder / kExportedReferenceFile;
  if (!fs::exists(path) && ExportedSetNumber(folder) >= 0)
    path = folder.parent_path() / kExportedReferenceFile;
  if (!fs::exists(path)) return std::nullopt;
  const std::string shape =
      ": needs 'reference: {camera: NAME, exposure_us: US, gain_db: DB, gain_in_db: BOOL}'";
  try {
    const YAML::Node root = YAML::LoadFile(path.string());
    const YAML::Node r = root.IsMap() ? root["reference"] : YAML::Node();
    if (!r || !r.IsMap() || !r["camera"] || !r["exposure_us"])
      throw InputError(path.string() + shape);
    ExposureReference out;
    out.where = path.string();
    const auto read = [&](const char* key, auto* value) {
      try {
        if (r[key]) *value = r[key].as<std::decay_t<decltype(*value)>>();
      } catch (const YAML::Exception& e) {
        throw InputError(path.string() + ": reference." + key + ": " + e.what() + shape);
      }
    };
    read("camera", &out.camera);
    read("exposure_us", &out.exposure_us);
    read("gain_db", &out.gain_db);
    read("gain_in_db", &out.gain_in_db);
    if (!(out.exposure_us > 0) || !std::isfinite(out.exposure_us))
      throw InputError(path.string() + ": reference.exposure_us must be a finite time > 0, not " +
                       fmt::format("{:g}", out.exposure_us));
    if (!std::isfinite(out.gain_db) || std::abs(out.gain_db) > 1000)
      throw InputError(path.string() + ": reference.gain_db must be a gain within +-1000 dB, not " +
                       fmt::format("{:g}", out.gain_db));
    return out;
  } catch (const YAML::Exception& e) {
    throw InputError(path.string() + ": not such a file (" + e.what() + ")" + shape);
  }
}

namespace {

// The formats for a folder of one frame set: its own pixel_formats.yaml, or that of the export
// it belongs to (a folder named frame_NNNNNN whose parent holds the export's sets.csv); `folder`
// absolute and canonical.
std::vector<ExportedFormat> FrameFolderFormats(const fs::path& folder, const Rig& rig) {
  if (fs::exists(folder / kExportedFormatsFile)) return ReadExportedFormats(folder.string(), rig);
  if (ExportedSetNumber(folder) >= 0)
    return ReadExportedFormats(folder.parent_path().string(), rig);
  return std::vector<ExportedFormat>(rig.cameras.size());
}

// The exposure factors an export's sets.csv gives, per set number, per rig camera: its
// <camera>_exposure columns (ExposureOfFrame's ratio), <camera>_exposure_start (its part that is
// the camera's start against the first camera's; 1 in exports before 2026-12-05) and
// <camera>_exposure_known (0 where the
// factor is not known: a gain changed in a device's own units, a damaged record); none for a
// sets.csv without them (an export before 2026-12-04, StreamPix's). A row whose set number or
// exposure is not one is kept as the error that reading that set raises (a DataError naming the
// file, its line and the column), so that a damaged row costs its own set only.
struct ExportedExposures {
  std::map<std::size_t, std::vector<FrameExposure>> sets;
  std::map<std::size_t, std::string> damaged;  // set number -> what is wrong with its row
  std::vector<std::string> unreadable;         // rows without a set number
};
ExportedExposures ReadExportedExposures(const fs::path& sets_csv, const Rig& rig) {
  ExportedExposures out;
  std::istringstream in(ReadFile(sets_csv.string()));
  auto cells = [](std::string line) {
    if (!line.empty() && line.back() == '\r') line.pop_back();  // a CRLF copy
    return SplitCsvRow(line);
  };
  std::string line;
  if (!std::getline(in, line)) return out;
  const std::vector<std::string> header = cells(line);
  auto column_of = [&](const std::string& name) {
    const auto it = std::find(header.begin(), header.end(), name);
    return it == header.end() ? -1 : static_cast<int>(it - header.begin());
  };
  std::vector<int> ratio_column(rig.cameras.size()), known_column(rig.cameras.size()),
      start_column(rig.cameras.size());
  bool any = false;
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    ratio_column[c] = column_of(rig.cameras[c].name + "_exposure");
    known_column[c] = column_of(rig.cameras[c].name + "_exposure_known");
    start_column[c] = column_of(rig.cameras[c].name + "_exposure_start");
    any = any || ratio_column[c] >= 0;
  }
  if (!any) return out;
  for (int number = 2; std::getline(in, line); ++number) {
    const std::vector<std::string> row = cells(line);
    if (row.empty() || (row.size() == 1 && row[0].empty())) continue;
    const std::string at = sets_csv.string() + ", line " + std::to_string(number) + ": ";
    const std::string& first = row[0];
    if (first.empty() || first.size() > 18 ||
        !std::all_of(first.begin(), first.end(), [](char ch) { return ch >= '0' && ch <= '9'; })) {
      out.unreadable.push_back(at + "the set number '" + first + "' is not one");
      continue;
    }
    const std::size_t set = std::stoull(first);
    std::vector<FrameExposure> exposures(rig.cameras.size());
    std::string wrong;
    for (std::size_t c = 0; c < rig.cameras.size() && wrong.empty(); ++c) {
      const std::string& name = rig.cameras[c].name;
      const auto cell = [&](int column) {
        return column >= 0 && static_cast<std::size_t>(column) < row.size() ? row[column]
                                                                            : std::string();
      };
      const std::string ratio_cell = cell(ratio_column[c]), known_cell = cell(known_column[c]),
                        start_cell = cell(start_column[c]);
      if (ratio_cell.empty()) continue;  // no frame of it in that set
      // A factor, or the error naming its cell.
      const auto factor = [&](const std::string& text, const std::string& column, double* value) {
        char* end = nullptr;
        *value = std::strtod(text.c_str(), &end);
        if (*end == '\0' && *value >= 1 / kExposureRatioRange && *value <= kExposureRatioRange)
          return true;
        wrong = at + name + column + " '" + text + "' is not an exposure factor (" +
                fmt::format("{:g} to {:g}", 1 / kExposureRatioRange, kExposureRatioRange) + ")";
        return false;
      };
      double ratio = 1, start = 1;
      if (!factor(ratio_cell, "_exposure", &ratio)) break;
      if (!start_cell.empty() && !factor(start_cell, "_exposure_start", &start)) break;
      if (!known_cell.empty() && known_cell != "0" && known_cell != "1") {
        wrong = at + name + "_exposure_known '" + known_cell + "' is not 0 or 1";
        break;
      }
      FrameExposure& e = exposures[c];
      e.ratio = ratio;
      e.start_ratio = start;
      e.unknown = known_cell == "0";
      if (e.unknown)
        e.note = fmt::format(
            "'s exposure changed by a factor its recording does not give ({}; {:.3g} applied, "
            "the part it gives)",
            sets_csv.string(), ratio);
      else if (std::abs(ratio / start - 1) > kExposureChange)
        e.note = fmt::format(
            " exposed at {:.3g} times its start ({}; {:.3g} times the take's exposure): fitted at "
            "that exposure",
            ratio / start, sets_csv.string(), ratio);
    }
    if (wrong.empty())
      out.sets[set] = std::move(exposures);
    else
      out.damaged[set] = wrong;
  }
  return out;
}

// A set's exposures from an export's sets.csv into `out` (its ratios, flags and notes), when the
// file gives that set; a DataError when its row is damaged, or when a row without a set number
// may be it (a set the file does not give, among unreadable rows).
void ApplyExportedExposures(const ExportedExposures& exposures, std::size_t set, const Rig& rig,
                            SourceFrameSet* out) {
  if (const auto bad = exposures.damaged.find(set); bad != exposures.damaged.end())
    throw DataError(bad->second);
  const auto it = exposures.sets.find(set);
  if (it == exposures.sets.end()) {
    if (!exposures.unreadable.empty()) throw DataError(exposures.unreadable.front());
    return;
  }
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    out->exposure_ratio[c] = it->second[c].ratio;
    out->exposure_start_ratio[c] = it->second[c].start_ratio;
    out->exposure_unknown[c] = it->second[c].unknown;
    if (!it->second[c].note.empty()) out->notes.push_back(rig.cameras[c].name + it->second[c].note);
  }
}

// A Bayer layout applies to what DecodeFrame made of a mosaic, an RGB image (8 or 16 bits);
// anything else under that name is refused, naming the image.
void CheckMosaicImage(BayerLayout layout, int channels, const std::string& image) {
  if (layout == BayerLayout::kNone || channels == 3) return;
  throw DataError(image + ": " + std::string(kExportedFormatsFile) + " says its camera sent a " +
                  ToString(layout) + " Bayer mosaic, demosaiced to RGB, but the image has " +
                  std::to_string(channels) + " channel(s)");
}

}  // namespace

SourceFrameSet ReadFrameFolder(const Rig& rig, const std::string& dir, double exposure) {
  if (!fs::is_directory(dir)) throw InputError(dir + ": no such folder of camera images");
  SourceFrameSet out;
  out.images.resize(rig.cameras.size());
  out.linear.resize(rig.cameras.size());
  out.signal.resize(rig.cameras.size());
  const fs::path folder = fs::weakly_canonical(fs::absolute(dir));
  const std::vector<ExportedFormat> formats = FrameFolderFormats(folder, rig);
  out.bits.assign(rig.cameras.size(), 0);
  out.exposure_ratio.assign(rig.cameras.size(), 1.0);
  out.exposure_unknown.assign(rig.cameras.size(), false);
  out.exposure_start_ratio.assign(rig.cameras.size(), 1.0);
  // A set that an export wrote: its cameras' exposures as the export's sets.csv gives them.
  if (const long long set = ExportedSetNumber(folder); set >= 0)
    ApplyExportedExposures(ReadExportedExposures(folder.parent_path() / "sets.csv", rig),
                           static_cast<std::size_t>(set), rig, &out);
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    const RigCamera& camera = rig.cameras[c];
    out.mosaic.push_back(formats[c].mosaic);
    out.radiometry.push_back(camera.radiometry.ForHighBitWords(formats[c].wire_bits));
    const fs::path path = fs::path(dir) / (camera.name + ".png");
    if (!fs::exists(path)) {
      out.notes.push_back("no image for camera '" + camera.name + "' (" + path.string() +
                          "): camera left out");
      continue;
    }
    ImageU8 u8;
    ImageU16 u16;
    const int bits = ReadImage(path.string(), &u8, &u16);
    const int width = bits == 16 ? u16.width : u8.width;
    const int height = bits == 16 ? u16.height : u8.height;
    CheckMosaicImage(out.mosaic[c], bits == 16 ? u16.channels : u8.channels, path.string());
    out.bits[c] = bits;
    if (width != camera.model.width() || height != camera.model.height())
      throw DataError(path.string() + ": the image is " + std::to_string(width) + "x" +
                      std::to_string(height) + ", camera '" + camera.name + "' is " +
                      std::to_string(camera.model.width()) + "x" +
                      std::to_string(camera.model.height()));
    try {
      DecodeCameraImage(u8, u16, bits, exposure * out.exposure_ratio[c], out.radiometry[c],
                        &out.images[c], &out.linear[c], &out.signal[c]);
    } catch (const InputError& e) {
      throw DataError(path.string() + ": " + e.what());
    }
  }
  return out;
}

void FrameSourceSpec::Validate() const {
  const int kinds = !recording_dir.empty() + !seq_files.empty() + !images_dir.empty();
  if (kinds != 1)
    throw InputError(
        "frame source: give exactly one of a recording, StreamPix .seq files or an images folder");
  if (!seq_names.empty() && seq_names.size() != seq_files.size())
    throw InputError("frame source: " + std::to_string(seq_names.size()) + " camera names for " +
                     std::to_string(seq_files.size()) + " .seq files");
}

std::string FrameSourceSpec::Describe() const {
  if (!recording_dir.empty()) return "recording " + recording_dir;
  if (!seq_files.empty()) return std::to_string(seq_files.size()) + " StreamPix sequences";
  return "images " + images_dir;
}

int SourceFrameSet::present() const {
  int n = 0;
  for (const auto& i : images) n += !i.empty();
  return n;
}

namespace {

// Whether a recording's camera records its gain in dB (CameraSettings::gain_db as named): a
// simulated camera, and an Aravis camera with GenICam's Gain feature (SFNC: dB), which the driver
// sets when the device has it. An Aravis camera with GainRaw alone and a V4L2 camera (its gain
// control) take the number in the device's own units: their change of gain has no known factor.
bool GainInDecibels(const RecordingMetadata& metadata, int camera) {
  const RecordingCamera& rc = metadata.cameras.at(static_cast<std::size_t>(camera));
  if (rc.description.driver == "sim") return true;
  return rc.description.driver == "aravis" && metadata.features.count(rc.name + ".Gain") > 0;
}

}  // namespace

namespace {

// A camera's settings as one number: exposure time x (the gain as a factor where it is in dB);
// 0 where the settings are not a camera's.
double SettingsProduct(const CameraSettings& s, bool decibels) {
  if (!(s.exposure_us > 0) || !std::isfinite(s.exposure_us) || !std::isfinite(s.gain_db)) return 0;
  return s.exposure_us * (decibels ? std::pow(10.0, s.gain_db / 20.0) : 1.0);
}

// The take's reference camera: the recording's first that records its settings; the number of
// cameras when none does.
std::size_t ReferenceCamera(const RecordingMetadata& metadata) {
  std::size_t ref = 0;
  while (ref < metadata.cameras.size() &&
         !(SettingsProduct(metadata.cameras[ref].settings, false) > 0))
    ++ref;
  return ref;
}

}  // namespace

double ExposureReference::exposure_us_at_0db() const {
  return exposure_us * (gain_in_db ? std::pow(10.0, gain_db / 20.0) : 1.0);
}

StartExposure StartExposureOfCamera(const RecordingMetadata& metadata, int camera) {
  StartExposure out;
  const auto& cameras = metadata.cameras;
  const std::size_t me = static_cast<std::size_t>(camera);
  const RecordingCamera& rc = cameras.at(me);
  // The reference: the recording's first camera that records its settings; for the gain, the
  // first that records it in dB (a camera in dB compares its gain with that one's, even when the
  // reference's own gain is in a device's units).
  const std::size_t ref = ReferenceCamera(metadata);
  std::size_t gain_ref = 0;
  while (gain_ref < cameras.size() && !(GainInDecibels(metadata, int(gain_ref)) &&
                                        SettingsProduct(cameras[gain_ref].settings, true) > 0))
    ++gain_ref;
  if (ref >= cameras.size() || !(SettingsProduct(rc.settings, false) > 0)) return out;
  const bool decibels = GainInDecibels(metadata, camera) && gain_ref < cameras.size() &&
                        SettingsProduct(rc.settings, true) > 0;
  const double gain_db = decibels ? rc.settings.gain_db - cameras[gain_ref].settings.gain_db : 0;
  const double ratio =
      rc.settings.exposure_us / cameras[ref].settings.exposure_us * std::pow(10.0, gain_db / 20);
  if (std::abs(ratio - 1) <= kExposureChange) return out;
  std::string settings = fmt::format("{:g} us", rc.settings.exposure_us),
              reference =
                  fmt::format("{}'s {:g} us", cameras[ref].name, cameras[ref].settings.exposure_us);
  if (decibels) {
    settings += fmt::format(", {:g} dB", rc.settings.gain_db);
    reference += gain_ref == ref ? fmt::format(", {:g} dB", cameras[ref].settings.gain_db)
                                 : fmt::format(" and {}'s {:g} dB", cameras[gain_ref].name,
                                               cameras[gain_ref].settings.gain_db);
  }
  if (!(ratio >= 1 / kExposureRatioRange && ratio <= kExposureRatioRange)) {
    out.note = fmt::format(
        " started at {} against {}: a factor of {:g}, not believed (a damaged record?), so not "
        "applied",
        settings, reference, ratio);
    return out;
  }
  out.ratio = ratio;
  const bool uncompared = !decibels && rc.settings.gain_db != cameras[ref].settings.gain_db;
  out.note = fmt::format(
      " started at {}, {:.3g} times {} (the take's exposure is its start's){}: fitted at that "
      "exposure",
      settings, ratio, reference,
      uncompared ? fmt::format("; its gain {:g} against {:g} is in a device's own units, not "
                               "compared",
                               rc.settings.gain_db, cameras[ref].settings.gain_db)
                 : std::string());
  return out;
}

FrameExposure ExposureOfFrame(const RecordingMetadata& metadata, int camera,
                              const FrameInfo& frame) {
  FrameExposure out;
  out.start_ratio = out.ratio = StartExposureOfCamera(metadata, camera).ratio;
  const RecordingCamera& rc = metadata.cameras.at(static_cast<std::size_t>(camera));
  const CameraSettings& start = rc.settings;
  if (!(frame.exposure_us > 0) || !(start.exposure_us > 0) || !std::isfinite(frame.exposure_us) ||
      !std::isfinite(start.exposure_us) || !std::isfinite(frame.gain_db) ||
      !std::isfinite(start.gain_db))
    return out;
  const bool decibels = GainInDecibels(metadata, camera);
  const double ratio = frame.exposure_us / start.exposure_us *
                       (decibels ? std::pow(10.0, (frame.gain_db - start.gain_db) / 20.0) : 1.0);
  const bool gain_changed = frame.gain_db != start.gain_db;
  // The whole factor too, as an export's sets.csv is read back (false for NaN).
  const bool believed = ratio >= 1 / kExposureRatioRange && ratio <= kExposureRatioRange &&
                        out.start_ratio * ratio >= 1 / kExposureRatioRange &&
                        out.start_ratio * ratio <= kExposureRatioRange;
  if (believed) out.ratio = out.start_ratio * ratio;
  out.unknown = !believed || (!decibels && gain_changed);
  if (!believed)
    out.note = fmt::format(
        "'s frame records {:g} us, {:g} dB where the recording started at {:g} us, {:g} dB: a "
        "factor of {:g}, not believed (a damaged record?), so not applied",
        frame.exposure_us, frame.gain_db, start.exposure_us, start.gain_db, ratio);
  else if (!decibels && gain_changed)
    out.note = fmt::format(
        "'s gain is {:g} where the recording started at {:g}, in the device's own units ({} "
        "records no gain in dB): its factor is unknown, so this set's densities do not share the "
        "take's scale; split the take where the gain changed",
        frame.gain_db, start.gain_db, rc.description.driver);
  else if (std::abs(ratio - 1) > kExposureChange)
    out.note = fmt::format(
        " exposed at {:.3g} times the recording's start ({:g} us, {:g} dB; it started at {:g} us, "
        "{:g} dB): fitted at that exposure",
        ratio, frame.exposure_us, frame.gain_db, start.exposure_us, start.gain_db);
  return out;
}

struct FrameSource::Impl {
  FrameSourceSpec spec;
  Rig rig;
  std::vector<int> source_camera;  // per rig camera: its index in the source
  std::vector<std::string> notes;
  std::size_t sets = 0;
  std::unique_ptr<Recording> recording;
  std::vector<StreamPixSequence> seqs;
  std::vector<ExportedFormat> images_formats;  // a folder's, per rig camera
  ExportedExposures images_exposures;          // an export's folder's, per set
  // per rig camera: the model its frames decode with (SourceFrameSet::radiometry); a
  // recording's is decided again for each frame, by what it was sent in (WireBitsOf)
  std::vector<CameraRadiometry> radiometry;

  // Checks a decoded camera image against the rig camera's imager.
  void CheckSize(int c, std::size_t set, int width, int height) const {
    const CameraModel& m = rig.cameras[c].model;
    if (width != m.width() || height != m.height()) {
      throw DataError(spec.Describe() + ", set " + std::to_string(set) + ", camera '" +
                      rig.cameras[c].name + "': the frame is " + std::to_string(width) + "x" +
                      std::to_string(height) + ", its model's imager is " +
                      std::to_string(m.width()) + "x" + std::to_string(m.height()));
    }
  }

  void MatchCameras(const std::vector<std::string>& names) {
    source_camera.assign(rig.cameras.size(), -1);
    std::vector<std::string> missing;
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const auto it = std::find(names.begin(), names.end(), rig.cameras[c].name);
      if (it == names.end())
        missing.push_back(rig.cameras[c].name);
      else
        source_camera[c] = static_cast<int>(it - names.begin());
    }
    if (!missing.empty()) {
      std::string m, have;
      for (const auto& n : missing) m += (m.empty() ? "" : ", ") + n;
      for (const auto& n : names) have += (have.empty() ? "" : ", ") + n;
      throw InputError(spec.Describe() + ": no camera named " + m +
                       " (the rig's); the source has " +
                       (have.empty() ? std::string("none") : have));
    }
  }
};

FrameSource::FrameSource(const FrameSourceSpec& spec, const Rig& rig)
    : impl_(std::make_unique<Impl>()) {
  spec.Validate();
  impl_->spec = spec;
  impl_->rig = rig;
  for (const RigCamera& camera : rig.cameras) impl_->radiometry.push_back(camera.radiometry);
  if (!spec.recording_dir.empty()) {
    impl_->recording = std::make_unique<Recording>(Recording::Open(spec.recording_dir));
    impl_->notes = impl_->recording->recovery().notes;
    std::vector<std::string> names;
    for (const auto& c : impl_->recording->metadata().cameras) names.push_back(c.name);
    impl_->MatchCameras(names);
    impl_->sets = impl_->recording->num_sets();
    // A rig camera started at other settings than the take's reference: said once, here.
    for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
      const StartExposure start =
          StartExposureOfCamera(impl_->recording->metadata(), impl_->source_camera[c]);
      if (!start.note.empty()) impl_->notes.push_back(rig.cameras[c].name + start.note);
    }
  } else if (!spec.seq_files.empty()) {
    std::vector<std::string> names = spec.seq_names;
    if (names.empty())
      for (const auto& f : spec.seq_files) names.push_back(fs::path(f).stem().string());
    impl_->sets = ~std::size_t(0);
    for (const auto& f : spec.seq_files) {
      impl_->seqs.emplace_back(f);
      impl_->sets = std::min(impl_->sets, impl_->seqs.back().num_frames());
    }
    for (std::size_t s = 0; s < impl_->seqs.size(); ++s)
      if (impl_->seqs[s].num_frames() > impl_->sets)
        impl_->notes.push_back(
            spec.seq_files[s] + " has " + std::to_string(impl_->seqs[s].num_frames()) +
            " frames; the sets stop at the shortest sequence's " + std::to_string(impl_->sets));
    impl_->MatchCameras(names);
  } else {
    if (!fs::is_directory(spec.images_dir))
      throw InputError(spec.images_dir + ": no such folder of frame sets");
    // Sets are frame_000000, frame_000001, ... up to the first gap.
    while (fs::is_directory(fs::path(spec.images_dir) / SetName(impl_->sets))) ++impl_->sets;
    if (impl_->sets == 0)
      throw InputError(spec.images_dir + ": no frame_000000/ folder (the layout is " +
                       "DIR/frame_NNNNNN/<camera>.png)");
    std::vector<std::string> names;
    for (const auto& c : rig.cameras)
      if (fs::exists(fs::path(spec.images_dir) / SetName(0) / (c.name + ".png")))
        names.push_back(c.name);
    impl_->MatchCameras(names);
    impl_->images_formats = ReadExportedFormats(spec.images_dir, impl_->rig);
    // An export's folder: its cameras' exposures per set, as its sets.csv gives them.
    if (fs::exists(fs::path(spec.images_dir) / "sets.csv"))
      impl_->images_exposures =
          ReadExportedExposures(fs::path(spec.images_dir) / "sets.csv", impl_->rig);
    // An export of a camera that sent a 10- to 14-bit wire format: as from its recording.
    for (std::size_t c = 0; c < rig.cameras.size(); ++c)
      impl_->radiometry[c] =
          rig.cameras[c].radiometry.ForHighBitWords(impl_->images_formats[c].wire_bits);
  }
}

FrameSource::~FrameSource() = default;
FrameSource::FrameSource(FrameSource&&) noexcept = default;
FrameSource& FrameSource::operator=(FrameSource&&) noexcept = default;

std::size_t FrameSource::num_sets() const { return impl_->sets; }
const std::vector<std::string>& FrameSource::notes() const { return impl_->notes; }

std::optional<ExposureReference> FrameSource::exposure_reference() const {
  if (impl_->recording) return ExposureReferenceOf(impl_->recording->metadata());
  return impl_->spec.images_dir.empty() ? std::nullopt
                                        : ReadExportedReference(impl_->spec.images_dir);
}

std::optional<ExposureReference> ExposureReferenceOf(const RecordingMetadata& metadata) {
  const std::size_t ref = ReferenceCamera(metadata);
  if (ref >= metadata.cameras.size()) return std::nullopt;
  ExposureReference out;
  out.camera = metadata.cameras[ref].name;
  out.exposure_us = metadata.cameras[ref].settings.exposure_us;
  out.gain_db = metadata.cameras[ref].settings.gain_db;
  out.gain_in_db = GainInDecibels(metadata, static_cast<int>(ref));
  return out;
}

SourceFrameSet FrameSource::Read(std::size_t i, double exposure) const {
  if (i >= impl_->sets)
    throw std::out_of_range(impl_->spec.Describe() + ": set " + std::to_string(i) + " of " +
                            std::to_string(impl_->sets));
  const Rig& rig = impl_->rig;
  SourceFrameSet out;
  out.index = i;
  out.images.resize(rig.cameras.size());
  out.linear.resize(rig.cameras.size());
  out.signal.resize(rig.cameras.size());
  out.mosaic.assign(rig.cameras.size(), BayerLayout::kNone);
  out.bits.assign(rig.cameras.size(), 0);
  out.radiometry = impl_->radiometry;
  out.exposure_ratio.assign(rig.cameras.size(), 1.0);
  out.exposure_unknown.assign(rig.cameras.size(), false);
  out.exposure_start_ratio.assign(rig.cameras.size(), 1.0);
  bool have_id = false;
  // An export's folder: the set's cameras' exposures as its sets.csv gives them.
  if (!impl_->spec.images_dir.empty())
    ApplyExportedExposures(impl_->images_exposures, i, rig, &out);
  for (std::size_t c = 0; c < rig.cameras.size(); ++c) {
    const std::string& name = rig.cameras[c].name;
    ImageU8 u8;
    ImageU16 u16;
    int bits = 8;
    if (impl_->recording) {
      const std::optional<Frame> f = impl_->recording->ReadFrame(i, impl_->source_camera[c]);
      if (!f) {
        out.notes.push_back(name + " left out: no frame in set " + std::to_string(i) +
                            " (dropped)");
        continue;
      }
      if (f->info.status != FrameStatus::kOk) {
        out.notes.push_back(name + " left out: its frame is " + ToString(f->info.status));
        continue;
      }
      if (!have_id) {
        out.frame_id = f->info.frame_id;
        out.timestamp_ns = f->info.host_realtime_ns;
        have_id = true;
      }
      bits = DecodeFrame(*f, &u8, &u16);
      out.mosaic[c] = BayerLayoutOf(f->info.pixel_format);
      // Its exposure against the recording's start (a frame that records none says nothing).
      const FrameExposure e =
          ExposureOfFrame(impl_->recording->metadata(), impl_->source_camera[c], f->info);
      out.exposure_ratio[c] = e.ratio;
      out.exposure_start_ratio[c] = e.start_ratio;
      out.exposure_unknown[c] = e.unknown;
      if (!e.note.empty()) out.notes.push_back(name + e.note);
      // A frame that arrived in a 10- to 14-bit wire format holds its values in the words' high
      // bits: the rig's entry, counted in those bits or taken from the frame, is read for them.
      const std::string& wire =
          impl_->recording->metadata().cameras[impl_->source_camera[c]].settings.wire_format;
      out.radiometry[c] = rig.cameras[c].radiometry.ForHighBitWords(WireBitsOf(f->info, wire));
    } else if (!impl_->seqs.empty()) {
      const int s = impl_->source_camera[c];
      const Frame f = impl_->seqs[s].ReadFrame(i, s);
      if (!have_id) {
        out.frame_id = i;
        out.timestamp_ns = f.info.device_timestamp_ns;
        have_id = true;
      }
      bits = DecodeFrame(f, &u8, &u16);
      out.mosaic[c] = BayerLayoutOf(f.info.pixel_format);
    } else {
      const fs::path path = fs::path(impl_->spec.images_dir) / SetName(i) / (name + ".png");
      out.frame_id = i;
      if (!fs::exists(path)) {
        out.notes.push_back(name + " left out: no " + path.string());
        continue;
      }
      bits = ReadImage(path.string(), &u8, &u16);
      out.mosaic[c] = impl_->images_formats[c].mosaic;
      CheckMosaicImage(out.mosaic[c], bits == 16 ? u16.channels : u8.channels, path.string());
    }
    out.bits[c] = bits;
    const int width = bits == 16 ? u16.width : u8.width;
    const int height = bits == 16 ? u16.height : u8.height;
    impl_->CheckSize(static_cast<int>(c), i, width, height);
    try {
      // The frame's own exposure: its linear frame is radiance in the take's units.
      DecodeCameraImage(u8, u16, bits, exposure * out.exposure_ratio[c], out.radiometry[c],
                        &out.images[c], &out.linear[c], &out.signal[c]);
    } catch (const InputError& e) {
      throw DataError(impl_->spec.Describe() + ", set " + std::to_string(i) + ", camera '" + name +
                      "': " + e.what());
    }
  }
  return out;
}

void ChangeOptions::Validate() const {
  if (!(min_threshold_dn >= 0) || !(min_threshold_dn <= 255))
    throw InputError("ChangeOptions.min_threshold_dn must be in [0, 255]");
  if (!(noise_sigmas >= 0) || !std::isfinite(noise_sigmas))
    throw InputError("ChangeOptions.noise_sigmas must be finite and >= 0");
  if (!(max_changed_fraction >= 0) || !(max_changed_fraction <= 1))
    throw InputError("ChangeOptions.max_changed_fraction must be in [0, 1]");
}

ImageChange CompareImages(const ImageU8& a, const ImageU8& b, const ChangeOptions& options) {
  if (a.width != b.width || a.height != b.height || a.channels != b.channels)
    throw InputError("CompareImages: images of different sizes or channel counts");
  const int ch = a.channels;
  const std::size_t n = a.num_pixels();
  // Per pixel, the largest channel difference.
  std::vector<int> diff(n);
  std::vector<int> dark;
  for (std::size_t p = 0; p < n; ++p) {
    int d = 0, level = 0;
    for (int c = 0; c < ch; ++c) {
      const int x = a.pixels[p * ch + c], y = b.pixels[p * ch + c];
      d = std::max(d, std::abs(x - y));
      level = std::max(level, std::max(x, y));
    }
    diff[p] = d;
    if (level < 32) dark.push_back(d);
  }
  ImageChange out;
  if (dark.size() >= 1000) {
    auto mid = dark.begin() + static_cast<std::ptrdiff_t>(dark.size() / 2);
    std::nth_element(dark.begin(), mid, dark.end());
    out.noise_dn = 1.4826 * *mid;
  }
  out.threshold_dn = std::max(options.min_threshold_dn, options.noise_sigmas * out.noise_dn);
  std::size_t changed = 0;
  for (int d : diff) changed += d > out.threshold_dn;
  out.changed_fraction = n ? double(changed) / n : 0.0;
  return out;
}

}  // namespace flamerig
