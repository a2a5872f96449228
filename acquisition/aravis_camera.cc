#include "acquisition/aravis_camera.h"

#include <arpa/inet.h>
#include <arv.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

#include "acquisition/camera_drivers.h"
#include "core/error.h"

namespace flamerig {

namespace {

// Takes ownership of a GError and turns it into our error, naming the camera and the step.
void Check(GError* error, const std::string& camera, const std::string& what) {
  if (!error) return;
  const std::string message = error->message ? error->message : "unknown error";
  g_clear_error(&error);
  throw IoError("aravis camera '" + camera + "': " + what + ": " + message);
}

bool IsIpv4(const std::string& s) {
  in_addr a;
  return ::inet_pton(AF_INET, s.c_str(), &a) == 1;
}

FrameStatus StatusOf(ArvBufferStatus s) {
  switch (s) {
    case ARV_BUFFER_STATUS_SUCCESS:
      return FrameStatus::kOk;
    case ARV_BUFFER_STATUS_MISSING_PACKETS:
    case ARV_BUFFER_STATUS_WRONG_PACKET_ID:
    case ARV_BUFFER_STATUS_SIZE_MISMATCH:
    case ARV_BUFFER_STATUS_FILLING:
      return FrameStatus::kIncomplete;
    case ARV_BUFFER_STATUS_TIMEOUT:
      return FrameStatus::kTimeout;
    default:
      return FrameStatus::kError;
  }
}

}  // namespace

void EnableAravisFakeInterface() { arv_enable_interface("Fake"); }

// The Aravis device id of the camera whose serial number, or user id (DeviceUserID, read by
// opening each camera), is `wanted`; empty when none.
static std::string FindDeviceBySerialOrUserId(const std::string& wanted) {
  arv_update_device_list();
  const unsigned n = arv_get_n_devices();
  for (unsigned i = 0; i < n; ++i) {
    const char* serial = arv_get_device_serial_nbr(i);
    if (serial && wanted == serial) return arv_get_device_id(i);
  }
  for (unsigned i = 0; i < n; ++i) {
    GError* e = nullptr;
    const char* device = arv_get_device_id(i);
    if (!device) continue;
    ArvCamera* camera = arv_camera_new(device, &e);
    if (e || !camera) {
      g_clear_error(&e);
      continue;
    }
    const char* user =
        arv_device_get_string_feature_value(arv_camera_get_device(camera), "DeviceUserID", &e);
    const bool match = !e && user && wanted == user;
    g_clear_error(&e);
    g_object_unref(camera);
    if (match) return device;
  }
  return "";
}

std::vector<CameraDescription> DiscoverAravisCameras() {
  arv_update_device_list();
  std::vector<CameraDescription> out;
  for (unsigned i = 0; i < arv_get_n_devices(); ++i) {
    CameraDescription d;
    d.driver = "aravis";
    auto s = [](const char* p) { return std::string(p ? p : ""); };
    d.serial = s(arv_get_device_serial_nbr(i));
    d.id = d.serial.empty() ? s(arv_get_device_id(i)) : d.serial;
    d.vendor = s(arv_get_device_vendor(i));
    d.model = s(arv_get_device_model(i));
    d.address = s(arv_get_device_address(i));
    out.push_back(d);
  }
  return out;
}

struct AravisCamera::Impl {
  std::string id;
  std::string resolved;  // the Aravis device id a serial or user id led to (reconnects use it)
  // Guards `camera` against Close/Open on the camera thread while another thread (a live
  // exposure change, a software trigger) talks to the device.
  mutable std::mutex device_mutex;
  ArvCamera* camera = nullptr;
  ArvStream* stream = nullptr;
  gulong control_lost_handler = 0;
  CameraDescription description;
  FrameIdUnwrapper unwrapper{16, 1};
  std::int64_t last_timestamp_ns = -1;
  StreamCounters counters;
  std::uint64_t payload = 0;
  bool configured = false;
  bool streaming = false;  // between Start and Stop, whatever the connection does
  int buffers = 8;
  // Reads a buffer's chunk data (ChunkExposureTime, ChunkGain) where the camera sends it (its
  // ChunkModeActive and ChunkEnable set, in the config's features); made at the first such buffer.
  ArvChunkParser* chunks = nullptr;

  ArvDevice* device() const { return arv_camera_get_device(camera); }
  // The exposure and gain a buffer's chunk data give, over `info`'s (which stay where it gives
  // none). GenICam's ChunkGain is in dB where the camera's Gain is (SFNC); a GainRaw camera's
  // stays in its own units, as its recording says (frame_source.h).
  void ReadChunkSettings(ArvBuffer* buffer, FrameInfo* info) {
    {
      std::lock_guard<std::mutex> lock(device_mutex);
      if (!chunks && camera) chunks = arv_camera_create_chunk_parser(camera);
    }
    if (!chunks) return;
    GError* e = nullptr;
    const double exposure =
        arv_chunk_parser_get_float_value(chunks, buffer, "ChunkExposureTime", &e);
    if (!e && std::isfinite(exposure) && exposure > 0) info->exposure_us = exposure;
    g_clear_error(&e);
    const double gain = arv_chunk_parser_get_float_value(chunks, buffer, "ChunkGain", &e);
    if (!e && std::isfinite(gain)) info->gain_db = gain;
    g_clear_error(&e);
  }
  bool Has(const char* feature) const {
    GError* e = nullptr;
    const bool yes = arv_camera_is_feature_available(camera, feature, &e);
    g_clear_error(&e);
    return yes;
  }
};

namespace {
void OnControlLost(ArvDevice*, gpointer flag) {
  static_cast<std::atomic<bool>*>(flag)->store(false);  // Aravis' heartbeat thread: only a store
}
}  // namespace

AravisCamera::AravisCamera(const std::string& id, int camera_index)
    : impl_(std::make_unique<Impl>()), camera_index_(camera_index) {
  impl_->id = id;
  Open();
}

void AravisCamera::Open() {
  std::lock_guard<std::mutex> lock(impl_->device_mutex);
  const std::string& id = impl_->id;
  GError* error = nullptr;
  if (IsIpv4(id)) {
    // Straight to the address: discovery could answer on another interface (notes/aravis.md).
    GInetAddress* address = g_inet_address_new_from_string(id.c_str());
    ArvDevice* device = arv_gv_device_new(address, address, &error);
    g_object_unref(address);
    Check(error, id, "cannot open the GigE Vision device at this address");
    impl_->camera = arv_camera_new_with_device(device, &error);
    g_object_unref(device);  // the camera holds its own reference
  } else {
    impl_->camera = arv_camera_new(id.c_str(), &error);
    if (error) {
      // Not an Aravis device id: a serial number, or a user id (DeviceUserID) set on the camera.
      g_clear_error(&error);
      // Found once; a reconnect opens the same device id without opening every camera again.
      const std::string device =
          impl_->resolved.empty() ? FindDeviceBySerialOrUserId(id) : impl_->resolved;
      impl_->resolved = device;
      if (device.empty())
        throw IoError("aravis camera '" + id +
                      "': no camera with this device id, serial number, user id or address "
                      "(flamerig cameras lists them)");
      impl_->camera = arv_camera_new(device.c_str(), &error);
    }
  }
  Check(error, id, "cannot open");
  if (!impl_->camera) throw IoError("aravis camera '" + id + "': cannot open");
  auto s = [&](const char* p) { return std::string(p ? p : ""); };
  impl_->description.driver = "aravis";
  impl_->description.id = id;
  impl_->description.vendor = s(arv_camera_get_vendor_name(impl_->camera, &error));
  g_clear_error(&error);
  impl_->description.model = s(arv_camera_get_model_name(impl_->camera, &error));
  g_clear_error(&error);
  impl_->description.serial = s(arv_camera_get_device_serial_number(impl_->camera, &error));
  g_clear_error(&error);
  impl_->description.address = id;
  if (ARV_IS_GV_DEVICE(impl_->device())) {
    // Owned by the device (transfer none).
    GSocketAddress* a = arv_gv_device_get_device_address(ARV_GV_DEVICE(impl_->device()));
    if (a && G_IS_INET_SOCKET_ADDRESS(a)) {
      gchar* text =
          g_inet_address_to_string(g_inet_socket_address_get_address(G_INET_SOCKET_ADDRESS(a)));
      impl_->description.address = text;
      g_free(text);
    }
  }
  // Out-of-range feature values are errors, not silently written (Aravis' default is no check).
  arv_camera_set_range_check_policy(impl_->camera, ARV_RANGE_CHECK_POLICY_ENABLE);
  connected_ = true;
  impl_->control_lost_handler =
      g_signal_connect(impl_->device(), "control-lost", G_CALLBACK(OnControlLost), &connected_);
}

void AravisCamera::Close() {
  std::lock_guard<std::mutex> lock(impl_->device_mutex);
  if (impl_->stream) {
    g_object_unref(impl_->stream);
    impl_->stream = nullptr;
  }
  if (impl_->camera) {
    if (impl_->control_lost_handler)
      g_signal_handler_disconnect(impl_->device(), impl_->control_lost_handler);
    impl_->control_lost_handler = 0;
    g_object_unref(impl_->camera);
    impl_->camera = nullptr;
  }
  g_clear_object(&impl_->chunks);
}

bool AravisCamera::Reconnect() {
  if (connected_) return true;
  Close();  // no AcquisitionStop: every register access to a dead device blocks for seconds
  try {
    Open();
    if (impl_->configured) Configure(settings());  // with the exposure and gain changed live
    if (impl_->streaming) Start(impl_->buffers);
    impl_->last_timestamp_ns = -1;
    return true;
  } catch (const std::exception&) {
    Close();
    connected_ = false;
    return false;
  }
}

AravisCamera::~AravisCamera() {
  Stop();
  Close();
}

CameraDescription AravisCamera::description() const { return impl_->description; }

void AravisCamera::Configure(const CameraSettings& s) {
  s.Validate();
  if (!impl_->camera) throw IoError("aravis camera '" + impl_->id + "': not connected");
  if (impl_->stream)
    throw std::logic_error("aravis camera '" + impl_->id + "': Configure while streaming");
  if (s.ptp) CheckPtp();  // first: a camera that cannot take part is refused before any change
  ArvCamera* cam = impl_->camera;
  GError* e = nullptr;
  // A wire format (Mono12p, ...) by its GenICam name: the camera must list it.
  const WireFormat* wire = s.wire_format.empty() ? nullptr : WireFormatFromName(s.wire_format);
  const ArvPixelFormat wanted =
      static_cast<ArvPixelFormat>(wire ? wire->pfnc : PfncOf(s.pixel_format));
  if (wire)
    arv_camera_set_pixel_format_from_string(cam, wire->name, &e);
  else
    arv_camera_set_pixel_format(cam, wanted, &e);
  Check(e, impl_->id, "PixelFormat " + s.pixel_format_name());
  // The region: width/height 0 take the whole sensor less the offset. The offsets go to 0 first
  // so that a larger width fits, then the size, then the offsets.
  CameraSettings taken = s;
  gint wmin = 0, wmax = 0, hmin = 0, hmax = 0;
  arv_camera_get_width_bounds(cam, &wmin, &wmax, &e);
  g_clear_error(&e);
  arv_camera_get_height_bounds(cam, &hmin, &hmax, &e);
  g_clear_error(&e);
  if (impl_->Has("SensorWidth") && impl_->Has("SensorHeight")) {
    const gint64 sw = arv_device_get_integer_feature_value(impl_->device(), "SensorWidth", &e);
    g_clear_error(&e);
    const gint64 sh = arv_device_get_integer_feature_value(impl_->device(), "SensorHeight", &e);
    g_clear_error(&e);
    if (sw > 0 && (wmax <= 0 || sw < wmax)) wmax = static_cast<gint>(sw);
    if (sh > 0 && (hmax <= 0 || sh < hmax)) hmax = static_cast<gint>(sh);
  }
  if (taken.width == 0) taken.width = wmax - s.offset_x;
  if (taken.height == 0) taken.height = hmax - s.offset_y;
  const std::string size = std::to_string(taken.width) + "x" + std::to_string(taken.height) + "+" +
                           std::to_string(s.offset_x) + "+" + std::to_string(s.offset_y);
  if (taken.width < 1 || taken.height < 1 || (wmax > 0 && s.offset_x + taken.width > wmax) ||
      (hmax > 0 && s.offset_y + taken.height > hmax))
    throw InputError("aravis camera '" + impl_->id + "': region " + size +
                     " (Width/Height + OffsetX/OffsetY) does not fit the sensor, " +
                     std::to_string(wmax) + "x" + std::to_string(hmax));
  auto set_int = [&](const char* feature, gint64 value) {
    if (!impl_->Has(feature)) {
      if (value != 0) throw InputError("aravis camera '" + impl_->id + "': has no " + feature);
      return;
    }
    arv_device_set_integer_feature_value(impl_->device(), feature, value, &e);
    Check(e, impl_->id,
          std::string(feature) + " " + std::to_string(value) + " (region " + size + ", sensor " +
              std::to_string(wmax) + "x" + std::to_string(hmax) + ")");
  };
  set_int("OffsetX", 0);
  set_int("OffsetY", 0);
  set_int("Width", taken.width);
  set_int("Height", taken.height);
  set_int("OffsetX", s.offset_x);
  set_int("OffsetY", s.offset_y);
  // Aravis clamps out-of-range values to the nearest the camera allows: read back what it took.
  gint x = 0, y = 0, w = 0, h = 0;
  arv_camera_get_region(cam, &x, &y, &w, &h, &e);
  Check(e, impl_->id, "reading Width/Height");
  if (w != taken.width || h != taken.height || x != s.offset_x || y != s.offset_y) {
    throw InputError("aravis camera '" + impl_->id + "': region " + size +
                     " refused (the camera set " + std::to_string(w) + "x" + std::to_string(h) +
                     "+" + std::to_string(x) + "+" + std::to_string(y) + ")");
  }
  const ArvPixelFormat applied = arv_camera_get_pixel_format(cam, &e);
  Check(e, impl_->id, "reading PixelFormat");
  if (applied != wanted) {
    throw InputError("aravis camera '" + impl_->id + "': PixelFormat " + s.pixel_format_name() +
                     " refused");
  }
  // Exposure: SFNC ExposureTime, or ExposureTimeAbs on older GigE Vision cameras (and the fake).
  const char* exposure = impl_->Has("ExposureTime") ? "ExposureTime" : "ExposureTimeAbs";
  arv_device_set_float_feature_value(impl_->device(), exposure, s.exposure_us, &e);
  Check(e, impl_->id, std::string(exposure) + " " + std::to_string(s.exposure_us) + " us");
  if (impl_->Has("Gain")) {
    arv_device_set_float_feature_value(impl_->device(), "Gain", s.gain_db, &e);
    Check(e, impl_->id, "Gain " + std::to_string(s.gain_db) + " dB");
  } else if (impl_->Has("GainRaw")) {
    arv_device_set_integer_feature_value(impl_->device(), "GainRaw", std::llround(s.gain_db), &e);
    Check(e, impl_->id, "GainRaw " + std::to_string(std::llround(s.gain_db)));
  }
  switch (s.trigger) {
    case TriggerMode::kFreeRun:
      arv_camera_clear_triggers(cam, &e);
      Check(e, impl_->id, "TriggerMode Off");
      break;
    case TriggerMode::kSoftware:
      arv_camera_set_trigger(cam, "Software", &e);
      Check(e, impl_->id, "TriggerSource Software");
      break;
    case TriggerMode::kHardware:
      arv_camera_set_trigger(cam, s.trigger_source.c_str(), &e);
      Check(e, impl_->id, "TriggerSource " + s.trigger_source);
      break;
    case TriggerMode::kAction: {
      // SFNC: the action keys the camera answers to, then the trigger on Action1; scheduled
      // actions need the camera's PTP clock on.
      auto set_int = [&](const char* feature, std::int64_t value) {
        if (!impl_->Has(feature))
          throw InputError("aravis camera '" + impl_->id + "': has no " + feature +
                           " (it cannot take action commands)");
        arv_device_set_integer_feature_value(impl_->device(), feature, value, &e);
        Check(e, impl_->id, std::string(feature) + " " + std::to_string(value));
      };
      if (impl_->Has("ActionSelector")) set_int("ActionSelector", 1);
      set_int("ActionDeviceKey", s.action_device_key);
      set_int("ActionGroupKey", s.action_group_key);
      set_int("ActionGroupMask", s.action_group_mask);
      const char* ptp = impl_->Has("PtpEnable")     ? "PtpEnable"
                        : impl_->Has("GevIEEE1588") ? "GevIEEE1588"
                                                    : nullptr;
      if (!ptp)
        throw InputError("aravis camera '" + impl_->id +
                         "': has no PtpEnable or GevIEEE1588 (no PTP clock for "
                         "scheduled action commands)");
      arv_device_set_boolean_feature_value(impl_->device(), ptp, TRUE, &e);
      Check(e, impl_->id, std::string(ptp) + " on");
      arv_camera_set_trigger(cam, "Action1", &e);
      Check(e, impl_->id, "TriggerSource Action1");
      break;
    }
  }
  // Free-run: the rate. Triggered: set too, as the camera's ceiling; a camera without the feature
  // runs at its own rate.
  if (impl_->Has("AcquisitionFrameRate")) {
    if (impl_->Has("AcquisitionFrameRateEnable"))
      arv_device_set_boolean_feature_value(impl_->device(), "AcquisitionFrameRateEnable", TRUE, &e);
    g_clear_error(&e);
    arv_camera_set_frame_rate(cam, s.frame_rate_hz, &e);
    Check(e, impl_->id, "AcquisitionFrameRate " + std::to_string(s.frame_rate_hz));
    // arv_camera_set_frame_rate may switch triggers off: put the trigger back.
    if (s.trigger != TriggerMode::kFreeRun) {
      arv_camera_set_trigger(cam,
                             s.trigger == TriggerMode::kSoftware ? "Software"
                             : s.trigger == TriggerMode::kAction ? "Action1"
                                                                 : s.trigger_source.c_str(),
                             &e);
      Check(e, impl_->id, "TriggerSource");
    }
  }
  if (s.packet_size > 0 && arv_camera_is_gv_device(cam)) {
    arv_camera_gv_set_packet_size(cam, s.packet_size, &e);
    Check(e, impl_->id, "GevSCPSPacketSize " + std::to_string(s.packet_size));
  }
  // Any other feature by name, in the config's order; a value the camera changes is a refusal.
  for (const auto& [name, value] : s.features) {
    ArvGcNode* node = arv_device_get_feature(impl_->device(), name.c_str());
    if (!node || !ARV_IS_GC_FEATURE_NODE(node))
      throw InputError("aravis camera '" + impl_->id + "': has no feature '" + name + "'");
    arv_gc_feature_node_set_value_from_string(ARV_GC_FEATURE_NODE(node), value.c_str(), &e);
    Check(e, impl_->id, "feature " + name + " = " + value);
    const std::string now = FeatureAsString(name);
    if (!now.empty() && now != value) {
      // Numbers may come back formatted differently: compare them as numbers.
      char* end1 = nullptr;
      char* end2 = nullptr;
      const double a = std::strtod(now.c_str(), &end1), b = std::strtod(value.c_str(), &end2);
      if (*end1 != '\0' || *end2 != '\0' || std::abs(a - b) > 1e-9 * std::max(1.0, std::abs(b)))
        throw InputError("aravis camera '" + impl_->id + "': feature " + name + " = " + value +
                         " refused (the camera set " + now + ")");
    }
  }
  settings_ = taken;
  live_.Reset({taken.exposure_us, taken.gain_db});
  impl_->configured = true;
}

void AravisCamera::Start(int buffers) {
  if (impl_->stream) return;
  if (buffers < 2) throw InputError("aravis camera '" + impl_->id + "': at least 2 buffers");
  impl_->buffers = buffers;
  if (settings_.wire_format.empty())  // a wire format is unpacked into a buffer of its own
    pool_.Reserve(static_cast<std::size_t>(buffers), std::size_t(std::max(settings_.width, 0)) *
                                                         std::max(settings_.height, 0) *
                                                         BytesPerPixel(settings_.pixel_format));
  impl_->streaming = true;
  ArvCamera* cam = impl_->camera;
  GError* e = nullptr;
  impl_->payload = arv_camera_get_payload(cam, &e);
  Check(e, impl_->id, "PayloadSize");
  impl_->stream = arv_camera_create_stream(cam, nullptr, nullptr, &e);
  Check(e, impl_->id, "cannot create a stream");
  if (ARV_IS_GV_STREAM(impl_->stream)) {
    // A fixed, large socket buffer; no resend (measured: without it, loopback streams lose
    // packets; the fake cannot resend).
    g_object_set(impl_->stream, "socket-buffer", ARV_GV_STREAM_SOCKET_BUFFER_FIXED,
                 "socket-buffer-size", 4 << 20, "packet-resend", ARV_GV_STREAM_PACKET_RESEND_NEVER,
                 nullptr);
  }
  for (int i = 0; i < buffers; ++i)
    arv_stream_push_buffer(impl_->stream, arv_buffer_new(impl_->payload, nullptr));
  arv_camera_set_acquisition_mode(cam, ARV_ACQUISITION_MODE_CONTINUOUS, &e);
  g_clear_error(&e);
  arv_camera_start_acquisition(cam, &e);
  Check(e, impl_->id, "AcquisitionStart");
}

void AravisCamera::Stop() {
  impl_->streaming = false;
  if (!impl_->stream) return;
  if (!connected_) {  // a dead device: drop the stream without talking to it
    g_object_unref(impl_->stream);
    impl_->stream = nullptr;
    return;
  }
  GError* e = nullptr;
  arv_camera_stop_acquisition(impl_->camera, &e);
  g_clear_error(&e);  // a camera that is gone cannot be stopped; the stream goes anyway
  g_object_unref(impl_->stream);
  impl_->stream = nullptr;
}

std::optional<Frame> AravisCamera::Pop(std::int64_t timeout_ns) {
  if (!impl_->stream && impl_->streaming) {  // lost and not reconnected yet
    std::this_thread::sleep_for(std::chrono::nanoseconds(std::max<std::int64_t>(timeout_ns, 0)));
    return std::nullopt;
  }
  if (!impl_->stream) throw std::logic_error("aravis camera '" + impl_->id + "': Pop before Start");
  ArvBuffer* buffer = arv_stream_timeout_pop_buffer(
      impl_->stream, static_cast<guint64>(std::max<std::int64_t>(timeout_ns, 0) / 1000));
  guint64 completed = 0, failures = 0, underruns = 0;
  arv_stream_get_statistics(impl_->stream, &completed, &failures, &underruns);
  impl_->counters.underruns = underruns;
  impl_->counters.buffers_allocated = pool_.stats().allocated;
  if (!buffer) {
    ++impl_->counters.timeouts;
    return std::nullopt;
  }
  Frame f;
  f.info.camera = camera_index_;
  const SystemClock clock;
  f.info.host_monotonic_ns = clock.MonotonicNs();
  f.info.host_realtime_ns = clock.RealtimeNs();
  f.info.status = StatusOf(arv_buffer_get_status(buffer));
  f.info.device_frame_id = arv_buffer_get_frame_id(buffer);
  f.info.frame_id = impl_->unwrapper.Next(f.info.device_frame_id);
  f.info.device_timestamp_ns = static_cast<std::int64_t>(arv_buffer_get_timestamp(buffer));
  // The settings it was exposed with: the camera's chunk data where it sends them, else those in
  // force when its exposure began, by its first packet's arrival (live_exposure.h).
  const guint64 arrived = arv_buffer_get_system_timestamp(buffer);
  const ExposureSettings taken = live_.ForFrameEndingAt(
      arrived > 0 ? static_cast<std::int64_t>(arrived) : f.info.host_realtime_ns);
  f.info.exposure_us = taken.exposure_us;
  f.info.gain_db = taken.gain_db;
  if (arv_buffer_get_status(buffer) == ARV_BUFFER_STATUS_SUCCESS && arv_buffer_has_chunks(buffer))
    impl_->ReadChunkSettings(buffer, &f.info);
  f.info.width = settings_.width;
  f.info.height = settings_.height;
  f.info.pixel_format = settings_.pixel_format;
  const WireFormat* wire =
      settings_.wire_format.empty() ? nullptr : WireFormatFromName(settings_.wire_format);
  // A buffer the stream flagged may hold no image part: its size and format are not asked (Aravis
  // prints a CRITICAL for them), and the frame keeps the configured ones with its failed status.
  if (arv_buffer_get_status(buffer) == ARV_BUFFER_STATUS_SUCCESS &&
      arv_buffer_get_payload_type(buffer) == ARV_BUFFER_PAYLOAD_TYPE_IMAGE) {
    wire = nullptr;  // the buffer says which, and the frame keeps what it said
    f.info.width = arv_buffer_get_image_width(buffer);
    f.info.height = arv_buffer_get_image_height(buffer);
    const std::uint32_t sent = arv_buffer_get_image_pixel_format(buffer);
    PixelFormat p;
    if (const WireFormat* w = WireFormatFromCode(sent)) {
      wire = w;
      f.info.sent_pfnc = sent;
    } else if (PixelFormatFromPfnc(sent, &p)) {
      f.info.pixel_format = p;
      f.info.sent_pfnc = sent;
    } else {
      f.info.status = FrameStatus::kError;
    }
  }
  // The bytes of the image (the in-process fakes report a size of 0 though the bytes are there).
  // A wire format is unpacked into Mono16 or Bayer 16 here, before the frame is queued.
  if (wire) f.info.pixel_format = wire->stored;
  size_t size = 0;
  const auto* data = static_cast<const std::uint8_t*>(arv_buffer_get_data(buffer, &size));
  const std::size_t image_bytes =
      wire ? WireBytes(*wire, f.info.width, f.info.height)
           : std::size_t(f.info.width) * f.info.height * BytesPerPixel(f.info.pixel_format);
  if (data && f.info.width > 0 && f.info.height > 0 && image_bytes <= impl_->payload &&
      (size == 0 || size >= image_bytes)) {
    if (wire) {
      f.data = std::make_shared<const std::vector<std::uint8_t>>(
          UnpackTo16Bit(*wire, data, image_bytes, f.info.width, f.info.height));
    } else {
      // Out of Aravis' buffer into a pooled one (frame_pool.h): no allocation per frame.
      auto bytes = pool_.Acquire(image_bytes);
      std::memcpy(bytes->data(), data, image_bytes);
      f.data = std::move(bytes);
    }
  } else if (wire) {
    f.data = std::make_shared<const std::vector<std::uint8_t>>(
        std::size_t(std::max(f.info.width, 0)) * std::max(f.info.height, 0) * 2, 0);
    if (f.info.status == FrameStatus::kOk) f.info.status = FrameStatus::kIncomplete;
  } else {
    f.data = std::make_shared<const std::vector<std::uint8_t>>(image_bytes, 0);
    if (f.info.status == FrameStatus::kOk) f.info.status = FrameStatus::kIncomplete;
  }
  arv_stream_push_buffer(impl_->stream, buffer);  // back to the pool at once

  // Drops: frame-id gaps (wrap-aware) and, in free-run, timestamp gaps (the fake skips a slot it
  // overran without a frame-id gap).
  // A buffer without a timestamp (0: a failed one, seen from the in-process fakes) neither counts
  // nor becomes the reference: measured from it, the next frame's gap was 1.8e11 frames. A gap
  // longer than a minute is the device's clock jumping (a reset, a PTP step), not frames missed:
  // an outage that long is a disconnect, counted as one.
  impl_->counters.missing_by_id = impl_->unwrapper.missing();
  if (f.info.device_timestamp_ns > 0) {
    if (settings_.trigger == TriggerMode::kFreeRun && impl_->last_timestamp_ns > 0 &&
        f.info.device_timestamp_ns > impl_->last_timestamp_ns) {
      const double seconds = double(f.info.device_timestamp_ns - impl_->last_timestamp_ns) / 1e9;
      const double gap = seconds * settings_.frame_rate_hz;
      if (gap > 1.5 && seconds < 60)
        impl_->counters.missing_by_time += static_cast<std::uint64_t>(std::llround(gap)) - 1;
    }
    impl_->last_timestamp_ns = f.info.device_timestamp_ns;
  }
  ++impl_->counters.delivered;
  if (f.info.status != FrameStatus::kOk) ++impl_->counters.incomplete;
  return f;
}

void AravisCamera::SoftwareTrigger(std::int64_t) {
  std::lock_guard<std::mutex> lock(impl_->device_mutex);
  if (!impl_->camera || !connected_) return;
  GError* e = nullptr;
  arv_camera_software_trigger(impl_->camera, &e);
  if (e) {
    g_clear_error(&e);
    connected_ = false;  // a trigger that cannot be written: the device is not answering
  }
}

StreamCounters AravisCamera::counters() const { return impl_->counters; }

CameraSettings AravisCamera::settings() const {
  CameraSettings s = settings_;
  const ExposureSettings now = live_.Current();
  s.exposure_us = now.exposure_us;
  s.gain_db = now.gain_db;
  return s;
}

void AravisCamera::CheckPtp() {
  // SFNC PtpEnable/PtpStatus, or the older GevIEEE1588/GevIEEE1588Status.
  const bool sfnc = impl_->Has("PtpEnable");
  const char* enable = sfnc ? "PtpEnable" : impl_->Has("GevIEEE1588") ? "GevIEEE1588" : nullptr;
  if (!enable)
    throw InputError("aravis camera '" + impl_->id +
                     "': sync: ptp, but it has no PTP clock (no PtpEnable or GevIEEE1588); use "
                     "another sync mode or a camera with IEEE 1588");
  GError* e = nullptr;
  arv_device_set_boolean_feature_value(impl_->device(), enable, TRUE, &e);
  Check(e, impl_->id, std::string(enable) + " on");
  const char* status_feature = sfnc ? "PtpStatus" : "GevIEEE1588Status";
  if (!impl_->Has(status_feature)) return;  // on, but its lock cannot be read
  // A clock takes a few seconds to settle on its master: wait up to 10 s for Slave or Master.
  std::string status;
  for (int i = 0; i < 100; ++i) {
    if (sfnc && impl_->Has("PtpDataSetLatch")) {
      arv_device_execute_command(impl_->device(), "PtpDataSetLatch", &e);
      g_clear_error(&e);
    }
    status = FeatureAsString(status_feature);
    if (status == "Slave" || status == "Master") return;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  throw IoError("aravis camera '" + impl_->id + "': sync: ptp, but its PTP clock is " +
                (status.empty() ? std::string("unreadable") : status) +
                " after 10 s (not Slave or Master): is a PTP master on its network?");
}

bool AravisCamera::SetExposureGainLive(double exposure_us, double gain_db) {
  std::lock_guard<std::mutex> lock(impl_->device_mutex);
  if (!impl_->camera || !connected_) return false;
  GError* e = nullptr;
  const char* exposure = impl_->Has("ExposureTime") ? "ExposureTime" : "ExposureTimeAbs";
  // The change's moment: just before the write (a frame whose exposure began after it may be the
  // new settings'; the read-backs below take round trips).
  const std::int64_t at_ns = SystemClock().RealtimeNs();
  arv_device_set_float_feature_value(impl_->device(), exposure, exposure_us, &e);
  if (e) {
    g_clear_error(&e);
    return false;  // this camera locks it while streaming
  }
  // What the camera took (it rounds to its own steps), read back; what was asked where it cannot
  // be read.
  auto taken = [&](const char* feature, double asked, bool integer) {
    GError* r = nullptr;
    const double v =
        integer ? double(arv_device_get_integer_feature_value(impl_->device(), feature, &r))
                : arv_device_get_float_feature_value(impl_->device(), feature, &r);
    const bool read = !r && std::isfinite(v);
    g_clear_error(&r);
    return read ? v : asked;
  };
  const double exposure_taken = taken(exposure, exposure_us, false);
  const double gain_before = live_.Current().gain_db;
  const char* gain = impl_->Has("Gain") ? "Gain" : impl_->Has("GainRaw") ? "GainRaw" : nullptr;
  if (gain && std::string(gain) == "Gain")
    arv_device_set_float_feature_value(impl_->device(), gain, gain_db, &e);
  else if (gain)
    arv_device_set_integer_feature_value(impl_->device(), gain, std::llround(gain_db), &e);
  const bool gain_took = !e;
  g_clear_error(&e);
  const double gain_taken =
      gain && gain_took ? taken(gain, gain_db, std::string(gain) == "GainRaw") : gain_before;
  live_.Change({exposure_taken, gain_taken}, at_ns);
  return gain_took;
}

std::map<std::string, std::string> AravisCamera::FeatureState() const {
  // Held against a trigger or a live change from other threads, and a reconnect.
  std::lock_guard<std::mutex> lock(impl_->device_mutex);
  std::map<std::string, std::string> out;
  if (!impl_->camera || !connected_) return out;
  ArvGc* gc = arv_device_get_genicam(impl_->device());
  if (!gc) return out;
  // Every category from Root down; every readable feature that is not a command. Bounded, so a
  // malformed description with cycles cannot hang the arm.
  std::vector<std::string> pending = {"Root"};
  std::set<std::string> seen;
  while (!pending.empty() && seen.size() < 4096) {
    const std::string name = pending.back();
    pending.pop_back();
    if (!seen.insert(name).second) continue;
    ArvGcNode* node = arv_gc_get_node(gc, name.c_str());
    if (!node) continue;
    if (ARV_IS_GC_CATEGORY(node)) {
      for (const GSList* f = arv_gc_category_get_features(ARV_GC_CATEGORY(node)); f; f = f->next)
        pending.emplace_back(static_cast<const char*>(f->data));
      continue;
    }
    if (!ARV_IS_GC_FEATURE_NODE(node) || ARV_IS_GC_COMMAND(node)) continue;
    GError* e = nullptr;
    const bool available = arv_gc_feature_node_is_available(ARV_GC_FEATURE_NODE(node), &e) &&
                           arv_gc_feature_node_is_implemented(ARV_GC_FEATURE_NODE(node), &e);
    g_clear_error(&e);
    if (!available) continue;
    const std::string value = FeatureAsString(name);
    if (!value.empty()) out[name] = value;
  }
  return out;
}

std::string AravisCamera::AvailableValues(const std::string& name) const {
  if (!impl_->camera) return "";
  GError* e = nullptr;
  guint n = 0;
  const char** values = arv_device_dup_available_enumeration_feature_values_as_strings(
      impl_->device(), name.c_str(), &n, &e);
  g_clear_error(&e);
  std::string out;
  for (guint i = 0; values && i < n; ++i) out += (out.empty() ? "" : ", ") + std::string(values[i]);
  g_free(values);
  return out;
}

std::string AravisCamera::FeatureAsString(const std::string& name) const {
  if (!impl_->camera) return "";
  ArvGcNode* node = arv_device_get_feature(impl_->device(), name.c_str());
  if (!node || !ARV_IS_GC_FEATURE_NODE(node)) return "";
  GError* e = nullptr;
  const char* v = arv_gc_feature_node_get_value_as_string(ARV_GC_FEATURE_NODE(node), &e);
  const std::string out = (!e && v) ? v : "";
  g_clear_error(&e);
  return out;
}

namespace {

std::vector<std::pair<std::string, std::string>> AravisDetails(const CameraDescription& d) {
  AravisCamera camera(d.id, 0);
  std::vector<std::pair<std::string, std::string>> out;
  auto add = [&](const std::string& label, const std::string& value) {
    if (!value.empty()) out.emplace_back(label, value);
  };
  const std::string sw = camera.FeatureAsString("SensorWidth"),
                    sh = camera.FeatureAsString("SensorHeight");
  if (!sw.empty() && !sh.empty()) add("sensor", sw + "x" + sh);
  add("region", camera.FeatureAsString("Width") + "x" + camera.FeatureAsString("Height") + "+" +
                    camera.FeatureAsString("OffsetX") + "+" + camera.FeatureAsString("OffsetY"));
  add("pixel format", camera.FeatureAsString("PixelFormat"));
  add("formats", camera.AvailableValues("PixelFormat"));
  for (const char* f :
       {"ExposureTime", "ExposureTimeAbs", "ExposureAuto", "Gain", "GainRaw", "GainAuto", "Gamma",
        "BlackLevel", "BalanceWhiteAuto", "TriggerMode", "TriggerSource", "AcquisitionFrameRate",
        "DeviceUserID", "DeviceFirmwareVersion"})
    add(f, camera.FeatureAsString(f));
  return out;
}

}  // namespace

CameraDriver AravisCameraDriver() {
  CameraDriver d;
  d.name = "aravis";
  d.description = "GigE Vision and USB3 Vision cameras through Aravis";
  d.capabilities.action_commands = true;
  d.open = [](const CaptureCameraConfig& camera, int index,
              const DriverContext&) -> std::unique_ptr<Camera> {
    return std::make_unique<AravisCamera>(camera.id, index);
  };
  d.discover = &DiscoverAravisCameras;
  d.details = &AravisDetails;
  return d;
}

}  // namespace flamerig
