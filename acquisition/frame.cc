#include "acquisition/frame.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <bit>
#include <cstring>
#include <iterator>
#include <limits>
#include <stdexcept>

#include "core/error.h"

namespace flamerig {

// 16-bit formats are little-endian words (GenICam, V4L2, PNG as flamerig writes it through OpenCV)
// read in place: this host must be little-endian too.
static_assert(std::endian::native == std::endian::little, "flamerig reads 16-bit frames in place");

namespace {
// Each stored format's GenICam name, PFNC code (tests check them against Aravis' constants), bytes
// per pixel and Bayer cell, in PixelFormat's order.
struct StoredFormat {
  PixelFormat format;
  const char* name;
  std::uint32_t pfnc;
  int bytes;
  const char* cell;  // "" for a format that is not a mosaic
};
constexpr StoredFormat kStoredFormats[] = {
    {PixelFormat::kMono8, "Mono8", 0x01080001u, 1, ""},
    {PixelFormat::kMono16, "Mono16", 0x01100007u, 2, ""},
    {PixelFormat::kRgb8, "RGB8", 0x02180014u, 3, ""},
    {PixelFormat::kBayerRg8, "BayerRG8", 0x01080009u, 1, "RGGB"},
    {PixelFormat::kBayerGr8, "BayerGR8", 0x01080008u, 1, "GRBG"},
    {PixelFormat::kBayerGb8, "BayerGB8", 0x0108000Au, 1, "GBRG"},
    {PixelFormat::kBayerBg8, "BayerBG8", 0x0108000Bu, 1, "BGGR"},
    {PixelFormat::kBayerRg16, "BayerRG16", 0x0110002Fu, 2, "RGGB"},
    {PixelFormat::kBayerGr16, "BayerGR16", 0x0110002Eu, 2, "GRBG"},
    {PixelFormat::kBayerGb16, "BayerGB16", 0x01100030u, 2, "GBRG"},
    {PixelFormat::kBayerBg16, "BayerBG16", 0x01100031u, 2, "BGGR"},
};
static_assert(std::size(kStoredFormats) == std::size(kAllPixelFormats));
constexpr bool InEnumOrder() {
  for (std::size_t i = 0; i < std::size(kStoredFormats); ++i)
    if (static_cast<std::size_t>(kStoredFormats[i].format) != i) return false;
  return true;
}
static_assert(InEnumOrder(), "kStoredFormats is indexed by PixelFormat");

// The row of `format`, or null for a value outside the enum (a corrupt recording's).
const StoredFormat* Find(PixelFormat format) {
  const auto i = static_cast<std::size_t>(format);
  return i < std::size(kStoredFormats) ? &kStoredFormats[i] : nullptr;
}
}  // namespace

const char* ToString(PixelFormat format) {
  const StoredFormat* f = Find(format);
  return f ? f->name : "?";
}

PixelFormat PixelFormatFromName(const std::string& name) {
  for (const StoredFormat& f : kStoredFormats)
    if (name == f.name) return f.format;
  std::string known;  // "Mono8, Mono16, ... or BayerBG16"
  const std::size_t count = std::size(kStoredFormats);
  for (std::size_t i = 0; i < count; ++i)
    known += (i == 0 ? "" : i + 1 == count ? " or " : ", ") + std::string(kStoredFormats[i].name);
  throw InputError("pixel format '" + name + "': use " + known);
}

std::uint32_t PfncOf(PixelFormat format) {
  const StoredFormat* f = Find(format);
  return f ? f->pfnc : 0;
}

bool PixelFormatFromPfnc(std::uint32_t pfnc, PixelFormat* format) {
  for (const StoredFormat& f : kStoredFormats) {
    if (f.pfnc == pfnc) {
      *format = f.format;
      return true;
    }
  }
  return false;
}

int BytesPerPixel(PixelFormat format) {
  const StoredFormat* f = Find(format);
  return f ? f->bytes : 1;
}

bool IsBayer(PixelFormat format) { return BayerCell(format)[0] != '\0'; }

PixelFormat Bayer16Of(PixelFormat bayer) {
  for (const StoredFormat& f : kStoredFormats)
    if (IsBayer(bayer) && f.bytes == 2 && std::string(f.cell) == BayerCell(bayer)) return f.format;
  throw InputError(std::string("pixel format ") + ToString(bayer) + " is not a Bayer mosaic");
}

const char* BayerCell(PixelFormat format) {
  const StoredFormat* f = Find(format);
  return f ? f->cell : "";
}

namespace {
// PFNC codes (GenICam Pixel Format Naming Convention; tests check them against Aravis' constants).
// The Bayer ones come in the order RG, GR, GB, BG.
constexpr PixelFormat kMono = PixelFormat::kMono16, kRg = PixelFormat::kBayerRg16,
                      kGr = PixelFormat::kBayerGr16, kGb = PixelFormat::kBayerGb16,
                      kBg = PixelFormat::kBayerBg16;
constexpr WirePacking kWords = WirePacking::kWords16, kGigE = WirePacking::kGigEPacked,
                      kStream = WirePacking::kLsbBitStream;
constexpr WireFormat kWireFormats[] = {
    {"Mono10", 0x01100003u, 10, kWords, kMono},
    {"Mono12", 0x01100005u, 12, kWords, kMono},
    {"Mono14", 0x01100025u, 14, kWords, kMono},
    {"Mono10Packed", 0x010C0004u, 10, kGigE, kMono},
    {"Mono12Packed", 0x010C0006u, 12, kGigE, kMono},
    {"Mono10p", 0x010A0046u, 10, kStream, kMono},
    {"Mono12p", 0x010C0047u, 12, kStream, kMono},
    {"BayerRG10", 0x0110000Du, 10, kWords, kRg},
    {"BayerGR10", 0x0110000Cu, 10, kWords, kGr},
    {"BayerGB10", 0x0110000Eu, 10, kWords, kGb},
    {"BayerBG10", 0x0110000Fu, 10, kWords, kBg},
    {"BayerRG12", 0x01100011u, 12, kWords, kRg},
    {"BayerGR12", 0x01100010u, 12, kWords, kGr},
    {"BayerGB12", 0x01100012u, 12, kWords, kGb},
    {"BayerBG12", 0x01100013u, 12, kWords, kBg},
    {"BayerRG10Packed", 0x010C0027u, 10, kGigE, kRg},
    {"BayerGR10Packed", 0x010C0026u, 10, kGigE, kGr},
    {"BayerGB10Packed", 0x010C0028u, 10, kGigE, kGb},
    {"BayerBG10Packed", 0x010C0029u, 10, kGigE, kBg},
    {"BayerRG12Packed", 0x010C002Bu, 12, kGigE, kRg},
    {"BayerGR12Packed", 0x010C002Au, 12, kGigE, kGr},
    {"BayerGB12Packed", 0x010C002Cu, 12, kGigE, kGb},
    {"BayerBG12Packed", 0x010C002Du, 12, kGigE, kBg},
    {"BayerRG10p", 0x010A0058u, 10, kStream, kRg},
    {"BayerGR10p", 0x010A0056u, 10, kStream, kGr},
    {"BayerGB10p", 0x010A0054u, 10, kStream, kGb},
    {"BayerBG10p", 0x010A0052u, 10, kStream, kBg},
    {"BayerRG12p", 0x010C0059u, 12, kStream, kRg},
    {"BayerGR12p", 0x010C0057u, 12, kStream, kGr},
    {"BayerGB12p", 0x010C0055u, 12, kStream, kGb},
    {"BayerBG12p", 0x010C0053u, 12, kStream, kBg},
};
}  // namespace

const WireFormat* WireFormatFromName(const std::string& name) {
  for (const WireFormat& f : kWireFormats)
    if (name == f.name) return &f;
  return nullptr;
}

const WireFormat* WireFormatOfFrame(PixelFormat format, const std::string& wire_format) {
  if (wire_format.empty()) return nullptr;
  const WireFormat* wire = WireFormatFromName(wire_format);
  if (!wire || wire->stored == format) return wire;
  if (!IsBayer(wire->stored) || !IsBayer(format)) return nullptr;
  // The same depth and packing in the frame's layout (none for an 8-bit one).
  for (const WireFormat& f : kWireFormats)
    if (f.stored == format && f.bits == wire->bits && f.packing == wire->packing) return &f;
  return nullptr;
}

int WireBitsOf(PixelFormat format, const std::string& wire_format) {
  const WireFormat* wire = WireFormatOfFrame(format, wire_format);
  return wire ? wire->bits : 0;
}

namespace {
// The full scale of a frame of `format` whose values lie in the high `bits` (0: at its own scale).
int FullScaleOf(PixelFormat format, int bits) {
  if (BytesPerPixel(format) != 2) return 255;  // 8-bit mono, Bayer and RGB
  return bits == 0 ? 0xffff : ((1 << bits) - 1) << (16 - bits);
}
}  // namespace

int FullScaleValue(PixelFormat format, const std::string& wire_format) {
  return FullScaleOf(format, WireBitsOf(format, wire_format));
}

const WireFormat* WireFormatOfFrame(const FrameInfo& info,
                                    const std::string& settings_wire_format) {
  const WireFormat* sent = WireFormatFromCode(info.sent_pfnc);
  if (sent) return sent->stored == info.pixel_format ? sent : nullptr;
  PixelFormat as_stored;
  if (PixelFormatFromPfnc(info.sent_pfnc, &as_stored)) return nullptr;  // it came as it is
  return WireFormatOfFrame(info.pixel_format, settings_wire_format);    // not said, or not known
}

int WireBitsOf(const FrameInfo& info, const std::string& settings_wire_format) {
  const WireFormat* wire = WireFormatOfFrame(info, settings_wire_format);
  return wire ? wire->bits : 0;
}

int FullScaleValue(const FrameInfo& info, const std::string& settings_wire_format) {
  return FullScaleOf(info.pixel_format, WireBitsOf(info, settings_wire_format));
}

const WireFormat* WireFormatFromCode(std::uint32_t pfnc) {
  for (const WireFormat& f : kWireFormats)
    if (pfnc == f.pfnc) return &f;
  return nullptr;
}

std::size_t WireBytes(const WireFormat& format, int width, int height) {
  const std::size_t n = std::size_t(std::max(width, 0)) * std::size_t(std::max(height, 0));
  switch (format.packing) {
    case WirePacking::kWords16:
      return 2 * n;
    case WirePacking::kGigEPacked:
      return 3 * ((n + 1) / 2);
    case WirePacking::kLsbBitStream:
      return (n * std::size_t(format.bits) + 7) / 8;
  }
  return 0;
}

std::vector<std::uint8_t> UnpackTo16Bit(const WireFormat& format, const std::uint8_t* data,
                                        std::size_t bytes, int width, int height) {
  const std::size_t need = WireBytes(format, width, height);
  if (width < 0 || height < 0 || bytes != need || (need > 0 && !data)) {
    throw DataError(std::string(format.name) + " frame " + std::to_string(width) + "x" +
                    std::to_string(height) + ": " + std::to_string(bytes) + " bytes, expected " +
                    std::to_string(need));
  }
  const std::size_t n = std::size_t(width) * std::size_t(height);
  const int shift = 16 - format.bits;
  const std::uint32_t mask = (1u << format.bits) - 1;
  std::vector<std::uint8_t> out(2 * n);
  auto put = [&](std::size_t k, std::uint32_t v) {
    v = (v & mask) << shift;
    out[2 * k] = static_cast<std::uint8_t>(v);
    out[2 * k + 1] = static_cast<std::uint8_t>(v >> 8);
  };
  switch (format.packing) {
    case WirePacking::kWords16:
      for (std::size_t k = 0; k < n; ++k) put(k, data[2 * k] | std::uint32_t(data[2 * k + 1]) << 8);
      break;
    case WirePacking::kGigEPacked: {
      const int low = format.bits - 8;  // low bits of each pixel in the middle byte
      for (std::size_t k = 0; k < n; ++k) {
        const std::uint8_t* t = data + 3 * (k / 2);
        const std::uint32_t lows = (k % 2 == 0) ? t[1] : t[1] >> 4;
        put(k, std::uint32_t(t[k % 2 == 0 ? 0 : 2]) << low | (lows & ((1u << low) - 1)));
      }
      break;
    }
    case WirePacking::kLsbBitStream:
      for (std::size_t k = 0; k < n; ++k) {
        const std::size_t bit = k * std::size_t(format.bits);
        std::uint32_t window = 0;  // up to 3 bytes hold any 10- or 12-bit pixel
        for (std::size_t b = 0; b < 3 && bit / 8 + b < bytes; ++b)
          window |= std::uint32_t(data[bit / 8 + b]) << (8 * b);
        put(k, window >> (bit % 8));
      }
      break;
  }
  return out;
}

const char* ToString(FrameStatus status) {
  switch (status) {
    case FrameStatus::kOk:
      return "ok";
    case FrameStatus::kIncomplete:
      return "incomplete";
    case FrameStatus::kTimeout:
      return "timeout";
    case FrameStatus::kError:
      return "error";
  }
  return "?";
}

FrameIdUnwrapper::FrameIdUnwrapper(int bits, std::uint64_t wrap_to) : wrap_to_(wrap_to) {
  if (bits < 1 || bits > 64) throw InputError("FrameIdUnwrapper: bits must be in [1, 64]");
  modulus_minus_one_ =
      bits == 64 ? std::numeric_limits<std::uint64_t>::max() : (std::uint64_t(1) << bits) - 1;
  if (wrap_to > modulus_minus_one_)
    throw InputError("FrameIdUnwrapper: wrap_to outside the counter's range");
}

std::uint64_t FrameIdUnwrapper::Next(std::uint64_t device_id) {
  device_id &= modulus_minus_one_;
  if (!started_) {
    started_ = true;
    last_device_ = device_id;
    last_unwrapped_ = device_id;
    return device_id;
  }
  // Values in one cycle after the first wrap: wrap_to .. max, `cycle` of them.
  const std::uint64_t cycle = modulus_minus_one_ - wrap_to_ + 1;
  auto forward = [&](std::uint64_t from, std::uint64_t to) -> std::uint64_t {
    if (to >= from) return to - from;
    // Through the wrap: from .. max, then wrap_to .. to.
    return (modulus_minus_one_ - from) + (to >= wrap_to_ ? to - wrap_to_ : 0) + 1;
  };
  const std::uint64_t ahead = forward(last_device_, device_id);
  if (ahead != 0 && ahead <= cycle / 2) {
    missing_ += ahead - 1;
    last_unwrapped_ += ahead;
    last_device_ = device_id;
    return last_unwrapped_;
  }
  // A repeat or a step back: the frame belongs before the newest one.
  ++out_of_order_;
  const std::uint64_t behind = forward(device_id, last_device_);
  return behind <= last_unwrapped_ ? last_unwrapped_ - behind : 0;
}

int DecodeFrame(const Frame& frame, ImageU8* u8, ImageU16* u16) {
  const FrameInfo& in = frame.info;
  const std::size_t expect =
      std::size_t(std::max(in.width, 0)) * std::max(in.height, 0) * BytesPerPixel(in.pixel_format);
  if (in.width <= 0 || in.height <= 0 || frame.bytes() != expect) {
    throw DataError("camera " + std::to_string(in.camera) + " frame " +
                    std::to_string(in.frame_id) + ": " + std::to_string(frame.bytes()) +
                    " bytes for " + std::to_string(in.width) + "x" + std::to_string(in.height) +
                    " " + ToString(in.pixel_format));
  }
  const std::uint8_t* p = frame.data->data();
  *u8 = ImageU8();
  *u16 = ImageU16();
  switch (in.pixel_format) {
    case PixelFormat::kMono8:
      *u8 = ImageU8(in.width, in.height, 1);
      std::copy(p, p + expect, u8->pixels.begin());
      return 8;
    case PixelFormat::kMono16:
      *u16 = ImageU16(in.width, in.height, 1);
      std::memcpy(u16->pixels.data(), p, expect);
      return 16;
    case PixelFormat::kRgb8:
      *u8 = ImageU8(in.width, in.height, 3);
      std::copy(p, p + expect, u8->pixels.begin());
      return 8;
    default: {
      // OpenCV names a Bayer pattern by the second row's second and third pixels, GenICam by the
      // first row's first two: GenICam RG is OpenCV BG, and so on.
      const std::string cell = BayerCell(in.pixel_format);
      const int code = cell == "RGGB"   ? cv::COLOR_BayerBG2RGB
                       : cell == "GRBG" ? cv::COLOR_BayerGB2RGB
                       : cell == "GBRG" ? cv::COLOR_BayerGR2RGB
                                        : cv::COLOR_BayerRG2RGB;
      if (BytesPerPixel(in.pixel_format) == 2) {
        // Little-endian words, as Mono16 (this host's order: x86 and ARM run little-endian).
        std::vector<std::uint16_t> words(std::size_t(in.width) * in.height);
        std::memcpy(words.data(), p, expect);
        const cv::Mat raw(in.height, in.width, CV_16UC1, words.data());
        *u16 = ImageU16(in.width, in.height, 3);
        cv::Mat rgb(in.height, in.width, CV_16UC3, u16->pixels.data());
        cv::cvtColor(raw, rgb, code);
        return 16;
      }
      const cv::Mat raw(in.height, in.width, CV_8UC1, const_cast<std::uint8_t*>(p));
      *u8 = ImageU8(in.width, in.height, 3);
      cv::Mat rgb(in.height, in.width, CV_8UC3, u8->pixels.data());
      cv::cvtColor(raw, rgb, code);
      return 8;
    }
  }
}

}  // namespace flamerig
