// `flamerig export`: a recording's frame sets as standard image files, in the dataset layout that
// `flamerig reconstruct` and `flamerig fit` read (OUT/frame_NNNNNN/<camera>.png), with a CSV of
// what each set holds.
#ifndef FLAMERIG_PIPELINE_EXPORT_H_
#define FLAMERIG_PIPELINE_EXPORT_H_

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "core/progress.h"

namespace flamerig {

struct ExportOptions {
  std::size_t first = 0;                // first frame set
  std::size_t count = ~std::size_t(0);  // how many (clipped to the recording)
};

struct ExportSummary {
  std::size_t sets = 0, images = 0;
  std::size_t missing_frames = 0;  // cameras absent from a set (no file written for them)
  // Damaged frames (a DataError: lost to a damaged file, a checksum, a frame cut short, a pixel
  // format that cannot be decoded), each "set N, camera C: what", in order. They are left out and
  // the export goes on.
  std::vector<std::string> failed;
  // Warnings that lose no image: a camera whose frames changed format (or wire format) within the
  // take, "camera C: ...", when pixel_formats.yaml can name only its last good frame's.
  std::vector<std::string> notes;
  bool cancelled = false;       // the progress callback asked to stop (the sets before are whole)
  std::int64_t event_set = -1;  // an event recording: the first set after its trigger (else -1)
};

// Writes OUT/frame_NNNNNN/<camera name>.png (8-bit, or 16-bit for Mono16 and Bayer 16; Bayer
// demosaiced to RGB),
// OUT/exposure_reference.yaml (the take's exposure reference, when its cameras record their
// settings: frame_source.h's WriteExportedReference), OUT/pixel_formats.yaml (each camera's pixel
// format as its frames carried it, or the 10- to
// 14-bit wire format they were unpacked from, so that a Bayer camera's frames read back from here
// are fitted through its mosaic and a wire format's words read as the take's: frame_source.h) and
// OUT/sets.csv (set, trigger id, reference time, spread, then per camera frame id, status and
// exposure (`<camera>_exposure`: the frame's exposure time x gain over the take's reference, as
// `run` fits it, frame_source.h's ExposureOfFrame; `<camera>_exposure_known`, 0 where that
// factor is not known: a gain changed in a device's own units, a damaged record; and
// `<camera>_exposure_start`, its part that is the camera's start against the recording's first
// camera's, StartExposureOfCamera; a folder read back from here is decoded and fitted at it, as
// the recording would be), empty when missing, "damaged"
// for a frame that is lost or fails its checksum; for an event
// recording a last column `event`: "pre-trigger" for the ring's sets, the event's name on the
// first set after its trigger). The recording is
// opened with every salvage Recording::Open() does (acquisition/recording.h), so a damaged file
// costs only the frames it touched: each is reported in the summary and skipped, and every intact
// frame of its set is written. Throws RecordingError only when metadata.yaml cannot be read.
// Progress: stage "export", unit "sets"; a cancel stops after the current set.
ExportSummary ExportRecording(const std::string& recording_dir, const std::string& out_dir,
                              const ExportOptions& options,
                              const ProgressCallback& progress = nullptr);

// The same for StreamPix .seq files, one per camera (frame i of every file is set i, as the
// paper's hardware-triggered capture wrote them); `names` gives the camera names (default the
// file stems). Stops at the shortest sequence. A damaged frame is reported and left out; the other
// cameras of its set are written. OUT/pixel_formats.yaml gives each file's pixel format as read.
ExportSummary ExportStreamPix(const std::vector<std::string>& seq_files,
                              const std::vector<std::string>& names, const std::string& out_dir,
                              const ExportOptions& options,
                              const ProgressCallback& progress = nullptr);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_EXPORT_H_
