// The capture daemon's local control API, and its client (`flamerig ctl`).
//
// Endpoint: "unix:PATH" (the default: a Unix socket created with owner-only permissions, 0600) or
// "tcp:HOST:PORT", where HOST must be a loopback address unless the config sets allow_remote.
//
// Protocol: the client connects and sends one request line (at most 4096 bytes, ending in '\n',
// within 2 s, or it is refused); the server answers "ok N\n" or "error N\n" followed by an N-byte
// body, and closes. Requests:
//   status [yaml|json|table]  the daemon's status (cameras, fps, drops, bandwidth, last frame's
//                          age, queue fill, disk backlog, frame-set counters, pre-trigger ring,
//                          elapsed times, disk free and time left): YAML (the default), JSON, or a
//                          table for people (CaptureStatus::ToTable)
//   cameras                the cameras with their drivers, ids and settings (YAML)
//   arm | disarm           start or stop the cameras' streams (disarm closes a recording)
//   configure CAM KEY VAL  set width, height, pixel_format, frame_rate_hz, exposure_us or gain_db
//                          of a camera while disarmed (applied at the next arm); exposure_us and
//                          gain_db also while armed, live (CaptureDaemon::SetCameraSetting)
//   apply CAM KEY VAL      configure, live when it can, else disarm-configure-arm as one command
//                          unless recording (CaptureDaemon::ApplyCameraSetting; the live view's)
//   start NAME             start recording into data_dir/NAME; the body is the directory
//   stop                   stop recording; the body is the recorder's final counters (YAML)
//   event NAME             record the pre-trigger ring and go on recording into data_dir/NAME
//   preview CAMERA [K]     the latest frame of CAMERA (name or index), downscaled K times
//                          (default 4), as a PNG body
//   shutdown               stop the daemon (flamerig capture exits)
// Connections are served one at a time on the server's own thread; nothing a client does can stall
// capture, which runs on other threads and never waits for the control API.
#ifndef FLAMERIG_ACQUISITION_CONTROL_H_
#define FLAMERIG_ACQUISITION_CONTROL_H_

#include <atomic>
#include <string>
#include <thread>

#include "acquisition/capture.h"

namespace flamerig {

struct ControlReply {
  bool ok = false;
  std::string body;
};

// Executes one request line against the daemon (what the server does per connection). Never
// throws: a bad request becomes an error reply that says why. `shutdown_requested` is set by
// "shutdown".
ControlReply HandleControlRequest(CaptureDaemon& daemon, const std::string& line,
                                  std::atomic<bool>* shutdown_requested);

class ControlServer {
 public:
  // Binds the endpoint (throws IoError naming it when it cannot, or when a TCP host is
  // not loopback and allow_remote is false) and starts serving on its own thread.
  ControlServer(CaptureDaemon* daemon, const std::string& endpoint, bool allow_remote);
  ~ControlServer();  // stops serving, removes the Unix socket file
  bool shutdown_requested() const { return shutdown_requested_; }
  const std::string& endpoint() const { return endpoint_; }
  int port() const { return port_; }  // the TCP port bound (useful with tcp:127.0.0.1:0)

 private:
  void Serve();
  CaptureDaemon* daemon_;
  std::string endpoint_, unix_path_;
  int listen_fd_ = -1;
  int port_ = 0;
  std::atomic<bool> stop_{false}, shutdown_requested_{false};
  std::thread thread_;
};

// Sends one request and returns the reply. Throws IoError naming the endpoint when the
// daemon cannot be reached or the reply is malformed.
ControlReply ControlRequest(const std::string& endpoint, const std::string& line,
                            double timeout_s = 10);

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_CONTROL_H_
