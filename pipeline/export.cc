#include "pipeline/export.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "acquisition/recording.h"
#include "acquisition/streampix.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "core/format.h"
#include "core/image.h"
#include "pipeline/frame_source.h"

namespace flamerig {

namespace fs = std::filesystem;

namespace {

// 8-bit PNG, or 16-bit for Mono16 and Bayer 16; Bayer demosaiced to RGB.
void WriteFramePng(const Frame& f, const fs::path& path) {
  ImageU8 u8;
  ImageU16 u16;
  if (DecodeFrame(f, &u8, &u16) == 16)
    WritePng16(path.string(), u16);
  else
    WritePng(path.string(), u8);
}

// Reports set i of [first, end) done; true when the export must stop.
bool SetDone(const ProgressCallback& progress, std::size_t i, std::size_t first, std::size_t end) {
  Progress p;
  p.stage = "export";
  p.unit = "sets";
  p.done = static_cast<std::int64_t>(i - first + 1);
  p.total = static_cast<std::int64_t>(end - first);
  return ReportProgress(progress, p);
}

std::string SetName(std::size_t i) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%06zu", i);
  return name;
}

// Export writes into a new or empty folder: into one that holds an earlier export, the frame sets
// of both would mix (a shorter take's sets.csv beside a longer one's stale frames).
void RequireEmptyFolder(const std::string& out_dir) {
  std::error_code ec;
  if (fs::exists(out_dir, ec) && !fs::is_empty(out_dir, ec))
    throw InputError("export: " + out_dir +
                     " is not empty: give a new or empty folder (nothing was overwritten)");
}

}  // namespace

ExportSummary ExportRecording(const std::string& recording_dir, const std::string& out_dir,
                              const ExportOptions& options, const ProgressCallback& progress) {
  const Recording rec = Recording::Open(recording_dir);
  ExportSummary summary;
  if (options.first > 0 && options.first >= rec.num_sets())
    throw InputError("export: --first " + std::to_string(options.first) +
                     " is past the recording's last frame set (" + std::to_string(rec.num_sets()) +
                     " sets)");
  RequireEmptyFolder(out_dir);
  fs::create_directories(out_dir);
  std::ostringstream csv;
  // An event recording marks its sets: "pre-trigger" from the ring, "event" for the first live
  // set after the trigger.
  const RecordingMetadata& meta = rec.metadata();
  const bool event = !meta.event_name.empty();
  csv << "set,trigger_id,reference_ns,spread_ns";
  for (const auto& c : meta.cameras)
    csv << "," << c.name << "_frame_id," << c.name << "_status," << c.name << "_exposure," << c.name
        << "_exposure_known," << c.name << "_exposure_start";
  if (event) csv << ",event";
  csv << "\n";
  // The first set after the trigger, over the whole take (an export may start past it).
  std::int64_t first_live = -1;
  for (std::size_t i = 0; event && i < rec.num_sets() && first_live < 0; ++i)
    if (static_cast<std::int64_t>(rec.SetHeader(i).index) > meta.event_last_ring_set)
      first_live = static_cast<std::int64_t>(i);
  summary.event_set = first_live;
  // Each camera's frames as pixel_formats.yaml names them: its settings' format, then its last
  // good frame's (a driver may set a buffer's format itself).
  std::vector<FrameInfo> last(meta.cameras.size());
  std::vector<bool> have_good(meta.cameras.size(), false);  // a frame of status kOk read
  std::vector<bool> changed(meta.cameras.size(), false);    // and said so in a note
  // What pixel_formats.yaml calls camera c's frames like `info`: the wire format they were sent
  // in (WireFormatOfFrame: as the frame says, else as the settings say), else their own format.
  auto FormatName = [&](const FrameInfo& info, int c) -> std::string {
    const WireFormat* wire = WireFormatOfFrame(info, meta.cameras[c].settings.wire_format);
    return wire ? wire->name : ToString(info.pixel_format);
  };
  for (std::size_t c = 0; c < meta.cameras.size(); ++c)
    last[c].pixel_format = meta.cameras[c].settings.pixel_format;
  // A camera started at other settings than the first: its sets.csv factors count that too.
  for (std::size_t c = 0; c < meta.cameras.size(); ++c) {
    const StartExposure start = StartExposureOfCamera(meta, static_cast<int>(c));
    if (!start.note.empty()) summary.notes.push_back("camera " + meta.cameras[c].name + start.note);
  }
  const std::size_t first = std::min(options.first, rec.num_sets());
  const std::size_t end = first + std::min(options.count, rec.num_sets() - first);
  for (std::size_t i = first; i < end; ++i) {
    // Camera by camera: a damaged frame costs that frame, not its set.
    const FrameSet set = rec.SetHeader(i);
    const fs::path dir = fs::path(out_dir) / SetName(i);
    fs::create_directories(dir);
    csv << i << "," << set.trigger_id << "," << set.reference_ns << "," << set.spread_ns;
    for (int c = 0; c < rec.num_cameras(); ++c) {
      const std::string& camera = rec.metadata().cameras[c].name;
      if (!rec.HasFrame(i, c) && !rec.FrameLost(i, c)) {
        ++summary.missing_frames;
        csv << ",,,,,";
        continue;
      }
      std::string frame_id;
      try {
        const Frame f = *rec.ReadFrame(i, c);
        // A change of format between good frames is a note, once per camera.
        if (f.info.status == FrameStatus::kOk || !have_good[c]) {
          if (have_good[c] && !changed[c]) {
            const std::string was = FormatName(last[c], c), now = FormatName(f.info, c);
            if (now != was) {
              changed[c] = true;
              summary.notes.push_back("camera " + camera +
                                      ": its frames change format within the take (" + was +
                                      " to " + now + " at set " + std::to_string(i) +
                                      "); pixel_formats.yaml names its last good frame's");
            }
          }
          last[c] = f.info;
          have_good[c] = have_good[c] || f.info.status == FrameStatus::kOk;
        }
        frame_id = std::to_string(f.info.frame_id);
        WriteFramePng(f, dir / (camera + ".png"));
        // Its exposure against the take's reference, as `run` reads it from the recording.
        const FrameExposure e = ExposureOfFrame(meta, c, f.info);
        csv << "," << frame_id << "," << ToString(f.info.status) << "," << FormatNumber(e.ratio, 9)
            << "," << (e.unknown ? 0 : 1) << "," << FormatNumber(e.start_ratio, 9);
        ++summary.images;
      } catch (const DataError& e) {
        summary.failed.push_back("set " + std::to_string(i) + ", camera " + camera + ": " +
                                 e.what());
        csv << "," << frame_id << ",damaged,,,";
      }
    }
    if (event) {
      const bool ring = static_cast<std::int64_t>(set.index) <= meta.event_last_ring_set;
      csv << ","
          << (ring                                         ? "pre-trigger"
              : static_cast<std::int64_t>(i) == first_live ? meta.event_name
                                                           : std::string());
    }
    csv << "\n";
    ++summary.sets;
    if (SetDone(progress, i, first, end)) {
      summary.cancelled = true;
      break;
    }
  }
  WriteFileAtomically((fs::path(out_dir) / "sets.csv").string(), csv.str());
  std::vector<std::string> names, wire_formats;
  std::vector<PixelFormat> formats;
  for (std::size_t c = 0; c < meta.cameras.size(); ++c) {
    names.push_back(meta.cameras[c].name);
    formats.push_back(last[c].pixel_format);
    // The wire format the last good frame arrived in (FormatName above).
    const WireFormat* wire = WireFormatOfFrame(last[c], meta.cameras[c].settings.wire_format);
    wire_formats.push_back(wire ? wire->name : "");
  }
  WriteExportedFormats(out_dir, names, formats, wire_formats);
  // The take's exposure reference: read back, the folder knows its exposure as the recording does.
  if (const std::optional<ExposureReference> ref = ExposureReferenceOf(meta))
    WriteExportedReference(out_dir, *ref);
  return summary;
}

ExportSummary ExportStreamPix(const std::vector<std::string>& seq_files,
                              const std::vector<std::string>& names_in, const std::string& out_dir,
                              const ExportOptions& options, const ProgressCallback& progress) {
  if (seq_files.empty()) throw InputError("export: no .seq files");
  std::vector<std::string> names = names_in;
  if (names.empty())
    for (const auto& f : seq_files) names.push_back(fs::path(f).stem().string());
  if (names.size() != seq_files.size())
    throw InputError("export: " + std::to_string(names.size()) + " names for " +
                     std::to_string(seq_files.size()) + " .seq files");
  std::vector<StreamPixSequence> seqs;
  std::size_t n = ~std::size_t(0);
  for (const auto& f : seq_files) {
    seqs.emplace_back(f);
    n = std::min(n, seqs.back().num_frames());
  }
  if (options.first > 0 && options.first >= n)
    throw InputError("export: --first " + std::to_string(options.first) +
                     " is past the sequences' last frame set (" + std::to_string(n) + " sets)");
  RequireEmptyFolder(out_dir);
  fs::create_directories(out_dir);
  std::ostringstream csv;
  csv << "set";
  for (const auto& name : names) csv << "," << name << "_timestamp_ns";
  csv << "\n";
  ExportSummary summary;
  std::vector<PixelFormat> formats(seqs.size(), PixelFormat::kRgb8);  // each file's, as read
  const std::size_t first = std::min(options.first, n);
  const std::size_t end = first + std::min(options.count, n - first);
  for (std::size_t i = first; i < end; ++i) {
    const fs::path dir = fs::path(out_dir) / SetName(i);
    fs::create_directories(dir);
    csv << i;
    for (std::size_t c = 0; c < seqs.size(); ++c) {
      try {
        const Frame f = seqs[c].ReadFrame(i, static_cast<int>(c));
        formats[c] = f.info.pixel_format;
        WriteFramePng(f, dir / (names[c] + ".png"));
        csv << "," << f.info.device_timestamp_ns;
        ++summary.images;
      } catch (const DataError& e) {
        summary.failed.push_back("set " + std::to_string(i) + ", camera " + names[c] + ": " +
                                 e.what());
        csv << ",damaged";
      }
    }
    csv << "\n";
    ++summary.sets;
    if (SetDone(progress, i, first, end)) {
      summary.cancelled = true;
      break;
    }
  }
  WriteFileAtomically((fs::path(out_dir) / "sets.csv").string(), csv.str());
  WriteExportedFormats(out_dir, names, formats);
  return summary;
}

}  // namespace flamerig
