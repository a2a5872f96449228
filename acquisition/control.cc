#include "acquisition/control.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "acquisition/live_view.h"
#include "acquisition/thread_name.h"
#include "core/error.h"

namespace flamerig {

namespace {

constexpr std::size_t kMaxRequest = 4096;
constexpr int kRequestTimeoutMs = 2000;

std::vector<std::string> Words(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> w;
  for (std::string s; in >> s;) w.push_back(s);
  return w;
}

std::string CamerasYaml(const CaptureDaemon& daemon) {
  YAML::Emitter out;
  out << YAML::BeginSeq;
  for (std::size_t c = 0; c < daemon.config().cameras.size(); ++c) {
    const CaptureCameraConfig& cc = daemon.config().cameras[c];
    out << YAML::BeginMap << YAML::Key << "index" << YAML::Value << c;
    out << YAML::Key << "name" << YAML::Value << cc.name;
    out << YAML::Key << "driver" << YAML::Value << cc.driver;
    out << YAML::Key << "id" << YAML::Value << cc.id;
    out << YAML::Key << "width" << YAML::Value << cc.settings.width;
    out << YAML::Key << "height" << YAML::Value << cc.settings.height;
    out << YAML::Key << "pixel_format" << YAML::Value << cc.settings.pixel_format_name();
    out << YAML::Key << "trigger" << YAML::Value << ToString(cc.settings.trigger);
    out << YAML::Key << "exposure_us" << YAML::Value << cc.settings.exposure_us;
    out << YAML::Key << "gain_db" << YAML::Value << cc.settings.gain_db;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  return std::string(out.c_str()) + "\n";
}

std::string RecorderYaml(const RecorderStatus& s) {
  std::ostringstream o;
  o << "sets_recorded: " << s.sets_recorded << "\nsets_dropped: " << s.sets_dropped
    << "\nframes_recorded: " << s.frames_recorded << "\nbytes_written: " << s.bytes_written
    << "\nstopped_by_error: " << (s.stopped && !s.limit_reached ? "true" : "false")
    << "\nstopped_by_limit: " << (s.limit_reached ? "true" : "false") << "\n";
  if (!s.error.empty()) {  // as metadata.yaml keeps them: a fault, or the limit that ended it
    YAML::Emitter e;
    e << YAML::BeginMap << YAML::Key << (s.limit_reached ? "limit_reached" : "error") << YAML::Value
      << s.error << YAML::EndMap;
    o << e.c_str() << "\n";
  }
  return o.str();
}

std::string PreviewPng(const CaptureDaemon& daemon, const std::vector<std::string>& w) {
  if (w.size() < 2 || w.size() > 3) throw InputError("usage: preview CAMERA [K]");
  const auto& cams = daemon.config().cameras;
  int camera = -1;
  for (std::size_t c = 0; c < cams.size(); ++c)
    if (cams[c].name == w[1] || std::to_string(c) == w[1]) camera = static_cast<int>(c);
  if (camera < 0) throw InputError("preview: no camera '" + w[1] + "'");
  int k = 4;
  if (w.size() == 3) {
    char* end = nullptr;
    const long v = std::strtol(w[2].c_str(), &end, 10);
    if (*end != '\0' || v < 1 || v > 64) throw InputError("preview: K must be 1..64");
    k = static_cast<int>(v);
  }
  const std::shared_ptr<const FrameSet> set = daemon.LatestSet();
  if (!set || !set->frames[camera])
    throw InputError("preview: no frame from camera '" + cams[camera].name + "' yet");
  const Frame& f = *set->frames[camera];
  const cv::Mat small =
      PreviewImage(f, k, FullScaleValue(f.info, daemon.camera_settings(camera).wire_format));
  std::vector<std::uint8_t> png;
  cv::imencode(".png", small, png);
  return std::string(png.begin(), png.end());
}

bool SendAll(int fd, const std::string& s) {
  std::size_t done = 0;
  while (done < s.size()) {
    const ssize_t n = ::send(fd, s.data() + done, s.size() - done, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    done += static_cast<std::size_t>(n);
  }
  return true;
}

// Reads until '\n' (not included), at most `max` bytes, within `timeout_ms`. False on timeout,
// overflow or disconnect.
bool ReadLine(int fd, std::size_t max, int timeout_ms, std::string* line) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  line->clear();
  char buf[512];
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                          deadline - std::chrono::steady_clock::now())
                          .count();
    if (left <= 0) return false;
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left)) <= 0) return false;
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) return false;
    line->append(buf, static_cast<std::size_t>(n));
    const auto nl = line->find('\n');
    if (nl != std::string::npos) {
      line->resize(nl);
      return line->size() <= max;
    }
    if (line->size() > max) return false;
  }
}

struct Endpoint {
  bool is_unix = true;
  std::string path;  // unix
  std::string host;  // tcp
  int port = 0;
};

Endpoint ParseEndpoint(const std::string& endpoint) {
  Endpoint e;
  if (endpoint.rfind("unix:", 0) == 0) {
    e.path = endpoint.substr(5);
    if (e.path.empty() || e.path.size() >= sizeof(sockaddr_un{}.sun_path))
      throw InputError("control endpoint '" + endpoint + "': socket path empty or too long");
    return e;
  }
  if (endpoint.rfind("tcp:", 0) == 0) {
    const std::string rest = endpoint.substr(4);
    const auto colon = rest.rfind(':');
    if (colon == std::string::npos)
      throw InputError("control endpoint '" + endpoint + "': use tcp:HOST:PORT");
    e.is_unix = false;
    e.host = rest.substr(0, colon);
    try {
      e.port = std::stoi(rest.substr(colon + 1));
    } catch (...) {
      e.port = -1;
    }
    if (e.port < 0 || e.port > 65535)
      throw InputError("control endpoint '" + endpoint + "': bad port");
    return e;
  }
  throw InputError("control endpoint '" + endpoint + "': use unix:PATH or tcp:HOST:PORT");
}

}  // namespace

ControlReply HandleControlRequest(CaptureDaemon& daemon, const std::string& line,
                                  std::atomic<bool>* shutdown_requested) {
  ControlReply r;
  try {
    const std::vector<std::string> w = Words(line);
    if (w.empty()) throw InputError("empty request");
    const std::string& cmd = w[0];
    auto arity = [&](std::size_t n) {
      if (w.size() != n)
        throw InputError("'" + cmd + "' takes " + std::to_string(n - 1) + " argument(s)");
    };
    if (cmd == "status") {
      if (w.size() > 2) throw InputError("usage: status [yaml|json|table]");
      const std::string form = w.size() == 2 ? w[1] : "yaml";
      const CaptureStatus s = daemon.status();
      if (form == "yaml")
        r.body = s.ToYaml();
      else if (form == "json")
        r.body = s.ToJson();
      else if (form == "table")
        r.body = s.ToTable();
      else
        throw InputError("status " + form + ": use yaml, json or table");
    } else if (cmd == "cameras") {
      arity(1);
      r.body = CamerasYaml(daemon);
    } else if (cmd == "start") {
      arity(2);
      r.body = daemon.StartRecording(w[1]) + "\n";
    } else if (cmd == "event") {
      arity(2);
      r.body = daemon.TriggerEvent(w[1]) + "\n";
    } else if (cmd == "stop") {
      arity(1);
      r.body = RecorderYaml(daemon.StopRecording());
    } else if (cmd == "preview") {
      r.body = PreviewPng(daemon, w);
    } else if (cmd == "arm") {
      arity(1);
      daemon.Start();
      r.body = "armed: cameras streaming\n";
    } else if (cmd == "disarm") {
      arity(1);
      daemon.Stop();
      r.body = "disarmed: cameras stopped (any recording closed)\n";
    } else if (cmd == "configure") {
      arity(4);
      daemon.SetCameraSetting(w[1], w[2], w[3]);
      r.body = "camera " + w[1] + ": " + w[2] + " = " + w[3] +
               (daemon.running() ? " (live, from the next frame)\n" : " (applied when armed)\n");
    } else if (cmd == "apply") {
      arity(4);
      r.body = "camera " + w[1] + ": " + w[2] + " = " + w[3] + " (" +
               daemon.ApplyCameraSetting(w[1], w[2], w[3]) + ")\n";
    } else if (cmd == "shutdown") {
      arity(1);
      if (shutdown_requested) *shutdown_requested = true;
      r.body = "shutting down\n";
    } else {
      throw InputError(
          "unknown request '" + cmd.substr(0, 32) +
          "': status [yaml|json|table], cameras, arm, disarm, configure CAMERA KEY VALUE, "
          "apply CAMERA KEY VALUE, start NAME, stop, event NAME, preview CAMERA [K], shutdown");
    }
    r.ok = true;
  } catch (const std::exception& e) {
    r.ok = false;
    r.body = std::string(e.what()) + "\n";
  }
  return r;
}

ControlServer::ControlServer(CaptureDaemon* daemon, const std::string& endpoint, bool allow_remote)
    : daemon_(daemon), endpoint_(endpoint) {
  const Endpoint e = ParseEndpoint(endpoint);
  if (e.is_unix) {
    listen_fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, e.path.c_str(), sizeof(addr.sun_path) - 1);
    std::error_code ec;
    if (std::filesystem::exists(e.path, ec)) {
      // A socket left by a daemon that died: remove it if nobody answers on it.
      const int probe = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
      const bool alive = ::connect(probe, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
      ::close(probe);
      if (alive) {
        ::close(listen_fd_);
        throw IoError("control socket " + e.path + ": another daemon is listening");
      }
      if (!std::filesystem::is_socket(e.path, ec)) {
        ::close(listen_fd_);
        throw IoError("control socket " + e.path + ": exists and is not a socket");
      }
      std::filesystem::remove(e.path, ec);
    }
    const mode_t old = ::umask(0077);  // owner-only from the moment it exists
    const int rc = ::bind(listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
    ::umask(old);
    if (rc != 0) {
      const std::string why = std::strerror(errno);
      ::close(listen_fd_);
      throw IoError("control socket " + e.path + ": " + why);
    }
    ::chmod(e.path.c_str(), 0600);
    unix_path_ = e.path;
  } else {
    in_addr host{};
    if (::inet_pton(AF_INET, e.host.c_str(), &host) != 1)
      throw InputError("control endpoint " + endpoint + ": host must be an IPv4 address");
    const bool loopback = (ntohl(host.s_addr) >> 24) == 127;
    if (!loopback && !allow_remote) {
      throw InputError("control endpoint " + endpoint +
                       ": not a loopback address; set allow_remote: true to open the "
                       "control API to the network");
    }
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int one = 1;
    ::setsockopt(listen_fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr = host;
    addr.sin_port = htons(static_cast<std::uint16_t>(e.port));
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
      const std::string why = std::strerror(errno);
      ::close(listen_fd_);
      throw IoError("control endpoint " + endpoint + ": " + why);
    }
    socklen_t len = sizeof addr;
    ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len);
    port_ = ntohs(addr.sin_port);
  }
  if (::listen(listen_fd_, 8) != 0) {
    ::close(listen_fd_);
    throw IoError("control endpoint " + endpoint + ": listen: " + std::strerror(errno));
  }
  thread_ = std::thread([this] {
    NameThisThread("fr-control");
    Serve();
  });
}

ControlServer::~ControlServer() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  ::close(listen_fd_);
  if (!unix_path_.empty()) {
    std::error_code ec;
    std::filesystem::remove(unix_path_, ec);
  }
}

void ControlServer::Serve() {
  while (!stop_) {
    pollfd p{listen_fd_, POLLIN, 0};
    if (::poll(&p, 1, 100) <= 0) continue;
    const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (fd < 0) continue;
    std::string line;
    ControlReply reply;
    if (!ReadLine(fd, kMaxRequest, kRequestTimeoutMs, &line)) {
      reply.body = "request refused: one line of at most 4096 bytes within 2 s\n";
    } else {
      reply = HandleControlRequest(*daemon_, line, &shutdown_requested_);
    }
    SendAll(fd,
            (reply.ok ? "ok " : "error ") + std::to_string(reply.body.size()) + "\n" + reply.body);
    ::close(fd);
  }
}

ControlReply ControlRequest(const std::string& endpoint, const std::string& line,
                            double timeout_s) {
  const Endpoint e = ParseEndpoint(endpoint);
  int fd = -1;
  int rc = -1;
  if (e.is_unix) {
    fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, e.path.c_str(), sizeof(addr.sun_path) - 1);
    rc = ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
  } else {
    // A host name (the rig's computer) or an IPv4 address; the daemon listens on IPv4.
    addrinfo hints{};
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* found = nullptr;
    const int gai = ::getaddrinfo(e.host.c_str(), std::to_string(e.port).c_str(), &hints, &found);
    if (gai != 0 || !found)
      throw IoError("cannot reach the capture daemon at " + endpoint + ": no such host '" + e.host +
                    "' (" + ::gai_strerror(gai) + ")");
    fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    rc = ::connect(fd, found->ai_addr, found->ai_addrlen);
    ::freeaddrinfo(found);
  }
  if (rc != 0) {
    const std::string why = std::strerror(errno);
    ::close(fd);
    throw IoError("cannot reach the capture daemon at " + endpoint + " (" + why +
                  "); is `flamerig capture` running?");
  }
  if (!SendAll(fd, line + "\n")) {
    ::close(fd);
    throw IoError("control " + endpoint + ": the daemon closed the connection");
  }
  std::string header;
  const int ms = static_cast<int>(timeout_s * 1000);
  // The header line, then exactly N bytes of body.
  std::string data;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(ms);
  char buf[65536];
  std::size_t need = std::string::npos, body_at = 0;
  bool ok = false;
  for (;;) {
    if (need != std::string::npos && data.size() >= body_at + need) break;
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                          deadline - std::chrono::steady_clock::now())
                          .count();
    pollfd p{fd, POLLIN, 0};
    if (left <= 0 || ::poll(&p, 1, static_cast<int>(left)) <= 0) {
      ::close(fd);
      throw IoError("control " + endpoint + ": no reply within " + std::to_string(timeout_s) +
                    " s");
    }
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) {
      ::close(fd);
      throw IoError("control " + endpoint + ": reply cut short");
    }
    data.append(buf, static_cast<std::size_t>(n));
    if (need == std::string::npos) {
      const auto nl = data.find('\n');
      if (nl == std::string::npos) continue;
      const std::vector<std::string> h = Words(data.substr(0, nl));
      if (h.size() != 2 || (h[0] != "ok" && h[0] != "error")) {
        ::close(fd);
        throw IoError("control " + endpoint + ": malformed reply");
      }
      ok = h[0] == "ok";
      need = std::stoull(h[1]);
      body_at = nl + 1;
    }
  }
  ::close(fd);
  return ControlReply{ok, data.substr(body_at, need)};
}

}  // namespace flamerig
