// The live view: what an operator looks at while setting up and recording a rig, in a browser.
//
// An embedded HTTP server (cpp-httplib, Debian's libcpp-httplib) serves one page and a small JSON
// API over the running CaptureDaemon:
//   GET  /                       the page: every camera's latest image with its clipped pixels in
//                                red, its histogram with the saturated share, fps, drops and
//                                missed triggers, the recording state and elapsed time, disk free
//                                and time left, and controls (arm, disarm, start NAME, stop, event
//                                NAME, exposure and gain per camera)
//   GET  /api/status             CaptureStatus::ToJson()
//   GET  /api/preview?camera=C&k=K   PNG of camera C's latest frame, 1/K size (K 1..64, default
//                                4), pixels at the camera's full scale drawn red (FullScaleValue: a
//                                10- to 14-bit wire format's highest word)
//   GET  /api/histogram?camera=C JSON {bins[256], saturated_share, clipped_pixels, sampled}
//   POST /api/control            body: one control request (acquisition/control.h) except
//                                `shutdown`; answers its reply, status 200 or 400
//
// Exposure and gain from the page: its Apply sends "apply CAMERA KEY VALUE", which changes them
// live when the camera can (every frame records the values it was taken with; recording goes on),
// and otherwise runs disarm, configure, arm when the rig is armed and not recording (refused while
// recording: the take would lose frames).
//
// Access: bound to loopback unless `allow_remote`; with allow_remote a token is required on every
// request (`?token=` or the X-Flamerig-Token header); without one in the options a random token is
// made and url() carries it. Everything is read from the daemon's latest frame set (shared, never
// copied) on the server's own threads: the page never makes capture wait. A PNG is encoded per
// request, so the page's cost is its polling rate times the encode; the capture benchmark states it.
//
// Thread safety: the server runs its own threads; construction and destruction from one thread.
#ifndef FLAMERIG_ACQUISITION_LIVE_VIEW_H_
#define FLAMERIG_ACQUISITION_LIVE_VIEW_H_

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "acquisition/capture.h"
#include "acquisition/frame.h"

namespace flamerig {

struct LiveViewOptions {
  std::string host = "127.0.0.1";
  int port = 0;               // 0: any free port (port() says which)
  bool allow_remote = false;  // bind a non-loopback host; a token is then required
  std::string token;          // required on every request when set (made when remote and empty)
  // "HOST:PORT" or "PORT"; throws InputError naming `where` when malformed.
  static LiveViewOptions Parse(const std::string& listen, const std::string& where);
};

// A frame's histogram: 256 bins over the format's range (the top 8 bits of 16-bit pixels; every
// channel of colour formats), on every `step`-th pixel of every `step`-th row, and the pixels at
// or above `full_scale` (clipped: the flame's detail there is lost). `full_scale` 0: the frame's
// own (FullScaleValue of its info: the format's maximum, or below it for a frame that says it was
// sent in a 10- to 14-bit wire format; the live view passes its camera's, settings included).
struct FrameHistogram {
  std::vector<std::uint64_t> bins = std::vector<std::uint64_t>(256, 0);
  std::uint64_t sampled = 0, clipped = 0;
  double saturated_share() const { return sampled ? double(clipped) / sampled : 0.0; }
};
FrameHistogram HistogramOf(const Frame& frame, int step = 2, int full_scale = 0);

// A frame as a person looks at it (the live view's and `flamerig ctl preview`'s picture): its
// decoded image (DecodeFrame: Bayer demosaiced), 8-bit BGR or grey as OpenCV writes it, 16-bit
// pixels scaled so that `full_scale` (0: the frame's own, as above) shows as 255, and 1/k of its
// size (k >= 1; area averaged). Pixels at or above `full_scale` in the frame's own bytes are drawn
// red when `mark_clipped`.
cv::Mat PreviewImage(const Frame& frame, int k, int full_scale = 0, bool mark_clipped = false);

class LiveViewServer {
 public:
  // Binds and starts serving; throws IoError naming host and port when it cannot bind, InputError
  // for a non-loopback host without allow_remote.
  LiveViewServer(CaptureDaemon* daemon, const LiveViewOptions& options);
  ~LiveViewServer();  // stops serving
  LiveViewServer(const LiveViewServer&) = delete;
  LiveViewServer& operator=(const LiveViewServer&) = delete;

  int port() const { return port_; }
  std::string url() const;  // http://HOST:PORT/ (with ?token=... when one is required)
  std::uint64_t requests() const { return requests_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  CaptureDaemon* daemon_;
  LiveViewOptions options_;
  int port_ = 0;
  std::atomic<std::uint64_t> requests_{0};
  std::thread thread_;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_LIVE_VIEW_H_
