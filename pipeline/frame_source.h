// Frame sets for per-frame processing, whatever they were recorded with: a flamerig recording, a set
// of StreamPix `.seq` files (one per camera, frame i of each is set i), or a folder of exported or
// simulated images (DIR/frame_NNNNNN/<camera>.png). A FrameSource hands out each set as one image per
// camera of a rig, in the rig's order, matched by camera name.
//
// Decoding: through each rig camera's radiometric model (DecodeCameraImage below). By default 8-bit
// frames (mono, RGB, Bayer demosaiced) are what the camera wrote, sRGB-encoded, and 16-bit frames
// (Mono16, 16-bit PNG) linear, value / 65535 being the linear signal (as `flamerig reconstruct`
// reads them); a rig camera's `radiometry` says otherwise (machine-vision raw is linear). Each
// camera's image comes as its linear signal and an RGB8 picture for the fit, and as a LinearFrame
// (radiance / exposure) for the tomography.
//
// A camera is left out of a set, with a note that says why, when: the recording has no frame of it
// in that set (a drop), its frame's status is not ok (incomplete, corrupt), or the images folder has
// no file for it. A frame whose size is not the rig camera's imager size is an error naming the
// camera, the set and both sizes; so is a frame whose checksum fails (RecordingError).
//
// Thread safety: Read() may be called from one thread at a time.
#ifndef FLAMERIG_PIPELINE_FRAME_SOURCE_H_
#define FLAMERIG_PIPELINE_FRAME_SOURCE_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "acquisition/frame.h"
#include "calibration/rig.h"
#include "fitting/mosaic.h"
#include "tomography/visual_hull.h"

namespace flamerig {

struct FrameSourceSpec {
  std::string recording_dir;           // a flamerig recording, or
  std::vector<std::string> seq_files;  // StreamPix sequences, one per camera, or
  std::vector<std::string> seq_names;  //   their camera names (default: the file stems)
  std::string images_dir;              // DIR/frame_NNNNNN/<camera>.png
  // Throws InputError unless exactly one kind of input is given.
  void Validate() const;
  std::string Describe() const;  // "recording DIR", "2 StreamPix sequences", "images DIR"
};

// A frame's exposure x gain that differs from its recording's start by more than this share is a
// change (SourceFrameSet::exposure_ratio); a camera's own rounding of the time it is given, a few
// parts in a thousand, is not.
inline constexpr double kExposureChange = 0.01;
// A frame's exposure ratio is believed within [1 / this, this]: beyond, a damaged record.
inline constexpr double kExposureRatioRange = 1e4;

struct RecordingMetadata;

// A recording's camera's start settings against the take's reference, its recording's first
// camera's (the take has one exposure, `--exposure`, a dataset's or fitted, and it is the
// exposure of that camera's start settings): the camera's exposure time x gain at the start over
// the reference's. The gains count where both cameras give them in dB (simulated cameras, Aravis
// cameras with GenICam's Gain); a gain in a device's own units is not compared, and is taken to
// be the one the camera's radiometric calibration was shot at (its shots' exposures count
// exposure time, and dB gain, in the take's units: radiometric_calibration.h). So a rig whose
// cameras record at different exposure times (two band-filtered mono cameras balanced for their
// bands, a camera stopped down) is fitted at each one's own. 1 where either camera records no
// settings, and where the factor lies beyond kExposureRatioRange (a damaged record: not applied,
// and the note says so). The note (to follow the camera's name) is empty within kExposureChange
// of 1.
// The camera whose settings at a recording's start the take's exposure is, and those settings;
// its gain counts where it is in dB (gain_in_db).
struct ExposureReference {
  std::string camera;
  std::string where;  // the export's exposure_reference.yaml it was read from; else empty
  double exposure_us = 0, gain_db = 0;
  bool gain_in_db = false;
  // exposure_us x (10^(gain_db / 20) where gain_in_db), in microseconds at 0 dB
  double exposure_us_at_0db() const;
};

struct StartExposure {
  double ratio = 1;
  std::string note;
};
StartExposure StartExposureOfCamera(const RecordingMetadata& metadata, int camera);
// A recording's reference: none when no camera records its settings.
std::optional<ExposureReference> ExposureReferenceOf(const RecordingMetadata& metadata);

// A recording's frame's exposure time x gain against the take's reference: its camera's start
// against the reference (StartExposureOfCamera, `start_ratio`) times the frame's against that
// start (what SourceFrameSet::exposure_ratio and exposure_unknown below hold for it), and the
// note on the frame's own change (to follow the camera's name: " exposed at 0.5 times ...",
// "'s gain is ..."; empty when the frame is within kExposureChange of its camera's start or
// records no exposure; a frame that records none is at its camera's start). `camera` indexes the
// recording's cameras. `flamerig export` writes the same factor into its sets.csv.
struct FrameExposure {
  double ratio = 1;
  double start_ratio = 1;
  bool unknown = false;
  std::string note;
};
FrameExposure ExposureOfFrame(const RecordingMetadata& metadata, int camera,
                              const FrameInfo& frame);

struct SourceFrameSet {
  std::size_t index = 0;            // the set's number in the source
  std::vector<ImageU8> images;      // per rig camera: RGB8, or empty when left out
  std::vector<LinearFrame> linear;  // per rig camera: radiance / exposure, or empty
  std::vector<ImageF> signal;       // per rig camera: the linear signal (DecodeCameraImage)
  // per rig camera: the frame's Bayer layout when it was a mosaic (the images above are its
  // demosaicing, fitting/mosaic.h), else kNone (RGB and mono frames, image files)
  std::vector<BayerLayout> mosaic;
  // per rig camera: the bits of the frame's codes as read (8 or 16; 0 when left out): how a
  // mosaic's codes decode (fitting/mosaic.h)
  std::vector<int> bits;
  // per rig camera: the radiometric model its frames were decoded with: the rig's, or for a frame
  // that arrived in a 10- to 14-bit wire format (values in the words' high bits: a recording's
  // frame that says it was sent in one, or does not say and is what its camera's wire format
  // unpacks into, acquisition/frame.h's WireFormatOfFrame; or an export whose pixel_formats.yaml
  // names the wire format), the rig's for such words (CameraRadiometry::ForHighBitWords); the
  // rig's for a camera left out. The fit's mosaic model takes the same
  std::vector<CameraRadiometry> radiometry;
  // per rig camera: the frame's exposure time x gain over the take's reference (ExposureOfFrame:
  // its camera's start settings against the recording's first camera's, times the frame's own
  // record against that start): a camera started at other settings than the first, or whose
  // exposure or gain was changed while it recorded (`ctl configure CAM exposure_us`, live), says
  // so here. 1 where the source does not say (image files, StreamPix, a camera left out).
  // The frame is decoded at that exposure (its linear frame is radiance in the take's units), and
  // `flamerig run` fits the camera at it (ChannelResponse::Exposed), so that the take keeps one
  // exposure and one density scale; a ratio beyond kExposureChange gets a note. The gain counts
  // where the recording gives it in dB (a simulated camera; an Aravis camera with GenICam's Gain
  // feature); a change of gain in a device's own units (Aravis GainRaw, V4L2's gain control) has
  // no known factor: the ratio is the exposure time's alone, and the note says so. A ratio beyond
  // kExposureRatioRange (a damaged record) is not applied either: 1, with a note.
  std::vector<double> exposure_ratio;
  // per rig camera: its exposure changed by a factor the record does not give (the two cases
  // above); `run` warns, as the set's densities are then not on the take's scale
  std::vector<bool> exposure_unknown;
  // per rig camera: the part of exposure_ratio that is its camera's start against the reference
  // (StartExposureOfCamera; 1 where the source does not say): what the frame's own change is
  // counted from
  std::vector<double> exposure_start_ratio;
  std::vector<std::string> notes;  // cameras left out and why; exposures that changed
  // The device frame id of the set's first present frame (recordings), the file's frame number
  // (StreamPix), or the set number (images): what a simulated camera replaying a dataset showed.
  std::uint64_t frame_id = 0;
  std::int64_t timestamp_ns = 0;  // the set's reference time, 0 when unknown
  int present() const;            // cameras with an image
};

class FrameSource {
 public:
  // Opens the source and matches its cameras to the rig's by name. Throws InputError
  // naming the rig cameras the source lacks (and the ones it has), or RecordingError /
  // IoError naming the file that cannot be read.
  FrameSource(const FrameSourceSpec& spec, const Rig& rig);
  ~FrameSource();
  FrameSource(FrameSource&&) noexcept;
  FrameSource& operator=(FrameSource&&) noexcept;

  std::size_t num_sets() const;
  // Set i (< num_sets()) decoded with `exposure` (> 0) for the linear frames.
  SourceFrameSet Read(std::size_t i, double exposure) const;
  // Notes about the whole source (a recovered recording's ignored tail, ...).
  const std::vector<std::string>& notes() const;
  // A recording's exposure reference (StartExposureOfCamera's), or an export's folder's
  // (ReadExportedReference): none for other sources, or for a recording whose cameras record no
  // settings.
  std::optional<ExposureReference> exposure_reference() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// One frame set from a folder, DIR/<camera>.png for every rig camera: 8-bit sRGB as the camera
// wrote it or 16-bit linear (value / 65535 is the linear signal; an export of a 10- to 14-bit
// wire format's words saturates at their highest, ForHighBitWords), decoded with `exposure` (> 0).
// The Bayer layouts (SourceFrameSet::mosaic) are those of DIR/pixel_formats.yaml, or, for a folder
// named frame_NNNNNN whose parent holds an export's sets.csv, the parent's (a set that `flamerig
// export` wrote); an image that a Bayer layout names but that is not RGB (8 or 16 bits) is a
// DataError naming it.
// A missing file leaves that camera out with a note in the set's notes; a damaged file or an image
// of the wrong size is a DataError naming the file.
SourceFrameSet ReadFrameFolder(const Rig& rig, const std::string& dir, double exposure);

// What `flamerig export` writes beside the frame sets it exports (OUT/pixel_formats.yaml): the
// pixel format each camera recorded, `cameras: {NAME: FORMAT, ...}` with GenICam's names (Mono8,
// BayerRG8, ...; the wire format the frames arrived in for a camera that sent one, BayerRG12p
// say, frame.h's WireFormatOfFrame: its 16-bit PNGs hold the values in the high bits, as
// flamerig stored them). A Bayer camera's PNGs hold its demosaicing (DecodeFrame), and whoever
// reads them back as a folder of frame sets fits them through that mosaic (fitting/mosaic.h). `wire_formats`: per camera, "" or the name of the wire
// format its frames arrived in; may be empty.
inline constexpr const char* kExportedFormatsFile = "pixel_formats.yaml";
void WriteExportedFormats(const std::string& dir, const std::vector<std::string>& cameras,
                          const std::vector<PixelFormat>& formats,
                          const std::vector<std::string>& wire_formats = {});
// One rig camera's entry of DIR/pixel_formats.yaml as the frame source reads it.
struct ExportedFormat {
  BayerLayout mosaic = BayerLayout::kNone;  // the layout of its mosaic, or none
  int wire_bits = 0;  // 10 to 14: its values are in the words' high bits (ForHighBitWords); or 0
};
// Each rig camera's entry by DIR/pixel_formats.yaml: the defaults for a camera it does not name,
// and for every camera when there is no such file (plain image files). Throws InputError naming
// the file and the entry for a file that is not such a map or a format that is not one.
std::vector<ExportedFormat> ReadExportedFormats(const std::string& dir, const Rig& rig);

// What `flamerig export` writes beside the frame sets it exports when the recording gives an
// exposure reference (FrameSource::exposure_reference): OUT/exposure_reference.yaml, `reference:
// {camera, exposure_us, gain_db, gain_in_db}`. A folder read back from there, through a rig that
// knows its exposure unit (a radiometric calibration's, Rig::exposure_unit_us), knows its
// exposure as the recording does; its sets.csv gives each camera's factor against it.
inline constexpr const char* kExportedReferenceFile = "exposure_reference.yaml";
void WriteExportedReference(const std::string& dir, const ExposureReference& reference);
// The reference of DIR (an export's folder) or, for a folder named frame_NNNNNN whose parent holds
// an export's sets.csv, of that parent; none without such a file (an export before 2026-12-05,
// plain image files). InputError naming the file and the key when it is malformed (an exposure
// time that is not a finite number > 0, a gain that is not finite).
std::optional<ExposureReference> ReadExportedReference(const std::string& dir);

// One camera's image as the tomography and the fit take it, decoded through the camera's
// radiometric model (calibration/radiometry.h) from what ReadImage or DecodeFrame gave (`bits` 8:
// *u8; 16: *u16): *signal (the linear signal, 0..1 with 1 saturated, 3 channels, mono
// replicated), *rgb8 (a picture: an 8-bit sRGB frame as it is, anything else its signal
// sRGB-encoded) and *linear (signal / exposure; saturated where a code reached the saturation
// level). With the default model, 8-bit frames are sRGB and 16-bit ones linear, as before cameras
// had one. Throws InputError for a bad exposure; for a one-channel (mono) frame from a camera the
// rig gives a colour response (colour cannot be fitted from one channel; the message says to give
// the sensor's sensitivity) or a colour frame from a mono camera; for a code above the camera's bit
// depth.
void DecodeCameraImage(const ImageU8& u8, const ImageU16& u16, int bits, double exposure,
                       const CameraRadiometry& radiometry, ImageU8* rgb8, LinearFrame* linear,
                       ImageF* signal);

// `rig` with every camera's frames read through the transfer function `spec` (ParseTransferSpec:
// "srgb", "linear", "gamma=G"), for folders of plain images whose rig says nothing (and a
// command-line override when it says something else); "" returns the rig as it is. It sets the
// transfer of frames in the camera's bit depth: 8-bit frames, and 16-bit ones when the rig gives a
// bit depth (without one, 16-bit frames stay linear). Throws InputError for a bad spec.
Rig WithInputTransfer(Rig rig, const std::string& spec);

// One camera's view of the question "did this frame change beyond noise since that one?".
struct ImageChange {
  double noise_dn = 0;          // robust noise of the difference, from pixels dark in both
  double threshold_dn = 0;      // a pixel differing by more than this changed
  double changed_fraction = 0;  // of the pixels
};

struct ChangeOptions {
  double min_threshold_dn = 3;         // a pixel never counts as changed below this difference
  double noise_sigmas = 5;             // nor below this many noise deviations of the difference
  double max_changed_fraction = 1e-4;  // a view is unchanged when at most this share changed
  void Validate() const;               // throws InputError naming the field
};

// Compares two images of one camera (same size and channels; else InputError). The
// noise of the difference is 1.4826 times the median absolute difference over the pixels that are
// dark (below 32) in both images, where only sensor noise can differ; with fewer than 1000 such
// pixels it is taken as 0 and the threshold is min_threshold_dn.
ImageChange CompareImages(const ImageU8& a, const ImageU8& b, const ChangeOptions& options);

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_FRAME_SOURCE_H_
