// What every camera driver delivers (DESIGN section 3): a frame and everything known about when and
// how it was taken.
//
// Times are int64 nanoseconds: the device's own timestamp (its clock, which may drift), and the
// host's monotonic and realtime clocks when the frame was received. Frame ids are 64-bit, unwrapped
// from the device's counter (GigE Vision counters are 16-bit, and Aravis' fake starts near the top
// and wraps to 1) by FrameIdUnwrapper, which also counts the frames a gap says were lost.
#ifndef FLAMERIG_ACQUISITION_FRAME_H_
#define FLAMERIG_ACQUISITION_FRAME_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/image.h"

namespace flamerig {

// The formats flamerig stores, by GenICam's names. A Bayer format is a colour camera's raw mosaic,
// one colour per site (BayerRG has R at (0, 0), G at (1, 0) and (0, 1), B at (1, 1)); the 16-bit
// ones are little-endian words (BayerRG16), which also hold 10- and 12-bit mosaics unpacked from
// the wire (below). Values are appended, never reordered: recordings store them as numbers.
enum class PixelFormat {
  kMono8,
  kMono16,
  kRgb8,
  kBayerRg8,
  kBayerGr8,
  kBayerGb8,
  kBayerBg8,
  kBayerRg16,
  kBayerGr16,
  kBayerGb16,
  kBayerBg16,
};
inline constexpr PixelFormat kAllPixelFormats[] = {
    PixelFormat::kMono8,     PixelFormat::kMono16,    PixelFormat::kRgb8,
    PixelFormat::kBayerRg8,  PixelFormat::kBayerGr8,  PixelFormat::kBayerGb8,
    PixelFormat::kBayerBg8,  PixelFormat::kBayerRg16, PixelFormat::kBayerGr16,
    PixelFormat::kBayerGb16, PixelFormat::kBayerBg16};
const char* ToString(PixelFormat format);
PixelFormat PixelFormatFromName(const std::string& name);  // "Mono8", ...; throws
// The format's PFNC / GigE Vision code (Mono8: 0x01080001; RGB8 is PFNC's RGB8Packed), which
// Aravis' ArvPixelFormat also is; and back: false for a code that is no format flamerig stores.
std::uint32_t PfncOf(PixelFormat format);
bool PixelFormatFromPfnc(std::uint32_t pfnc, PixelFormat* format);
int BytesPerPixel(PixelFormat format);
bool IsBayer(PixelFormat format);
// A Bayer format's 2 x 2 cell as GenICam names it ("RGGB", "GRBG", "GBRG", "BGGR"); "" otherwise.
const char* BayerCell(PixelFormat format);
// The 16-bit Bayer format with `bayer`'s cell (BayerRG8 -> BayerRG16); throws InputError for a
// format that is not Bayer.
PixelFormat Bayer16Of(PixelFormat bayer);

// A camera's pixel format on the wire when it is not one flamerig stores: mono or a Bayer mosaic at
// 10, 12 or 14 bits, in 16-bit words (Mono10, Mono12, Mono14, BayerRG10, BayerRG12: little-endian,
// the value in the low bits) or packed (Mono10Packed, Mono12Packed, BayerRG10Packed,
// BayerRG12Packed: GigE Vision's 2 pixels in 3 bytes; Mono10p, Mono12p, BayerRG10p, BayerRG12p:
// PFNC's LSB-first bit stream); the Bayer ones in all four layouts (RG, GR, GB, BG). Frames are
// unpacked as they arrive into Mono16 or the layout's Bayer 16 (`stored`) with the value in the
// high bits (v << (16 - bits)): black stays 0, the scale stays linear, and a value never clips.
// The recording's camera settings keep the wire format's name (`wire_format`).
enum class WirePacking {
  kWords16,      // one little-endian 16-bit word per pixel, the value in its low bits
  kGigEPacked,   // 2 pixels in 3 bytes: byte 0 and 2 hold the high 8 bits of pixel 0 and 1; byte
                 // 1 holds the low bits of pixel 0 from bit 0 and of pixel 1 from bit 4
  kLsbBitStream  // pixel k is bits [k * bits, (k + 1) * bits) of the frame, least significant first
};
struct WireFormat {
  const char* name;    // GenICam PixelFormat name, e.g. "Mono12p"
  std::uint32_t pfnc;  // its PFNC / GigE Vision code
  int bits;            // significant bits per pixel
  WirePacking packing;
  PixelFormat stored;  // what its frames are unpacked into: Mono16 or a Bayer 16 format
};
// The wire formats above by name; nullptr for any other name (including the stored formats).
const WireFormat* WireFormatFromName(const std::string& name);
// The wire format a frame of `format` arrived in, as far as its camera's settings tell: they name
// the format the camera was set to send (CameraSettings::wire_format). So: the settings' wire
// format where `format` is what it unpacks into; the same depth and packing in `format`'s Bayer
// layout where only the layout differs (a camera mirrored by ReverseX sends BayerGR12p under
// BayerRG12p settings); nullptr for "", a name that is no wire format, and a frame of another
// kind (8-bit, or mono under a Bayer wire format, or the reverse: a driver that delivered another
// format than the settings name). The rule for a frame that does not say what it was sent in
// (FrameInfo::sent_pfnc 0: a recording made before it was kept, a V4L2 camera) or says it in a
// code this flamerig does not know; the overloads on FrameInfo below are the one rule for reading
// a frame's values in the words' high bits: the live view's clipping, `export`'s
// pixel_formats.yaml and the pipeline's frame source.
const WireFormat* WireFormatOfFrame(PixelFormat format, const std::string& wire_format);
// That wire format's significant bits; 0 where there is none (the frame is at its own scale).
int WireBitsOf(PixelFormat format, const std::string& wire_format);
// The value a frame's pixels hold where its sensor clipped: 255 in an 8-bit format, 65535 in a
// 16-bit one, and in the words a `bits`-bit wire format is unpacked into (WireBitsOf), its highest
// value (2^bits - 1) << (16 - bits): 0xFFC0 for Mono10p, 0xFFF0 for BayerRG12p.
int FullScaleValue(PixelFormat format, const std::string& wire_format = "");
const WireFormat* WireFormatFromCode(std::uint32_t pfnc);
// Bytes of one width x height frame in `format` (whole frames; no line padding).
std::size_t WireBytes(const WireFormat& format, int width, int height);
// Unpacks one frame of `bytes` bytes into width * height 16-bit little-endian words (the bytes of
// a `format.stored` frame). Throws DataError when `bytes` is not WireBytes.
std::vector<std::uint8_t> UnpackTo16Bit(const WireFormat& format, const std::uint8_t* data,
                                        std::size_t bytes, int width, int height);

enum class FrameStatus {
  kOk,
  kIncomplete,  // packets or lines missing: the bytes are there but some are not the camera's
  kTimeout,     // the device stopped delivering it
  kError,       // the transport reported an error
};
const char* ToString(FrameStatus status);

struct FrameInfo {
  int camera = -1;                    // index of the camera in the rig
  std::uint64_t frame_id = 0;         // unwrapped
  std::uint64_t device_frame_id = 0;  // as the device counted it
  std::int64_t device_timestamp_ns = 0;
  std::int64_t host_monotonic_ns = 0;
  std::int64_t host_realtime_ns = 0;
  std::int64_t trigger_id = -1;  // the trigger that caused it, -1 when free-running or unknown
  double exposure_us = 0;
  double gain_db = 0;
  PixelFormat pixel_format = PixelFormat::kMono8;
  int width = 0, height = 0;
  FrameStatus status = FrameStatus::kOk;
  // The PFNC code of the format the camera sent this frame in, as its driver read it from the
  // buffer: a wire format's (Mono10p: 0x010A0046) where the driver unpacked it into
  // `pixel_format`, `pixel_format`'s own (PfncOf) where it arrived as stored (the simulated camera
  // says so too); 0 where not known (a V4L2 camera, a recording made before flamerig kept it).
  // Recorded with the frame.
  std::uint32_t sent_pfnc = 0;
};

// The wire format the frame `info` describes arrived in: the one its driver read from the buffer
// where it said (sent_pfnc; nullptr where that is a stored format's own code, or a wire format
// that is not unpacked into `info.pixel_format`), else (0, or a code that is neither) as its
// camera's settings say (`settings_wire_format`, WireFormatOfFrame above). So a camera that sent
// Mono10p under Mono12p settings is read at 10 bits, and a buffer that came as Mono16 at 16.
const WireFormat* WireFormatOfFrame(const FrameInfo& info, const std::string& settings_wire_format);
int WireBitsOf(const FrameInfo& info, const std::string& settings_wire_format);
int FullScaleValue(const FrameInfo& info, const std::string& settings_wire_format);

// A frame: its description and its bytes (row-major, width * height * BytesPerPixel, no padding).
// The bytes are shared so that a frame can sit in the recorder's queue and the preview at once
// without a copy.
struct Frame {
  FrameInfo info;
  std::shared_ptr<const std::vector<std::uint8_t>> data;
  std::size_t bytes() const { return data ? data->size() : 0; }
};

// A frame's pixels as an image: Mono8 -> 1 channel 8-bit, Mono16 -> 1 channel 16-bit, RGB8 -> RGB
// 8-bit, Bayer 8-bit -> RGB 8-bit and Bayer 16-bit -> RGB 16-bit by OpenCV's bilinear
// demosaicing. Fills *u8 or *u16 and returns the bit depth (8 or 16). Throws DataError
// naming the camera and frame when the bytes do not match the size and format.
int DecodeFrame(const Frame& frame, ImageU8* u8, ImageU16* u16);

// Unwraps a device frame counter of `bits` bits (1..64) into 64 bits and counts gaps. The counter may
// start anywhere, wraps from 2^bits - 1 to `wrap_to` (GigE Vision skips 0: wrap_to = 1).
class FrameIdUnwrapper {
 public:
  explicit FrameIdUnwrapper(int bits = 16, std::uint64_t wrap_to = 1);
  // The unwrapped id of the next device id. A step backwards by more than half the counter range is
  // a wrap; a small step backwards (a reordered or repeated frame) returns the id it would have had
  // and counts as out of order.
  std::uint64_t Next(std::uint64_t device_id);
  std::uint64_t missing() const { return missing_; }  // ids skipped by forward gaps
  std::uint64_t out_of_order() const { return out_of_order_; }

 private:
  std::uint64_t wrap_to_;
  std::uint64_t modulus_minus_one_;
  bool started_ = false;
  std::uint64_t last_device_ = 0;
  std::uint64_t last_unwrapped_ = 0;
  std::uint64_t missing_ = 0, out_of_order_ = 0;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_FRAME_H_
