#include "acquisition/live_view.h"

#include <httplib.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <random>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "acquisition/control.h"
#include "core/error.h"
#include "core/log.h"

namespace flamerig {

namespace {

// The page: plain HTML, CSS and JavaScript, no external resources (a rig's laptop may be offline).
// `?click=start&name=N` makes the page press its own Start button once the status has loaded (the
// browser test's way to click).
constexpr const char* kPage = R"HTML(<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>flamerig live view</title>
<style>
body { font-family: sans-serif; background: #1d1f21; color: #e0e0e0; margin: 12px; }
h1 { font-size: 18px; margin: 0 0 8px 0; }
#bar { display: flex; gap: 18px; align-items: center; flex-wrap: wrap; padding: 8px;
       background: #2a2d30; border-radius: 6px; margin-bottom: 10px; }
#state.rec { color: #ff5050; font-weight: bold; }
button { background: #3c4043; color: #fff; border: 1px solid #5f6368; padding: 4px 10px;
         border-radius: 4px; cursor: pointer; }
button.rec { background: #a01818; }
input { background: #111; color: #eee; border: 1px solid #555; width: 90px; }
#cams { display: flex; flex-wrap: wrap; gap: 12px; }
.cam { background: #2a2d30; border-radius: 6px; padding: 8px; width: 340px; }
.cam h2 { font-size: 15px; margin: 0 0 4px 0; }
.cam img { width: 320px; background: #000; display: block; min-height: 60px; }
.cam canvas { width: 320px; height: 70px; background: #111; display: block; margin-top: 4px; }
.num { font-variant-numeric: tabular-nums; }
.warn { color: #ffb040; }
.bad { color: #ff5050; }
#msg { color: #9ad; min-height: 1.2em; }
</style></head><body>
<h1>flamerig live view</h1>
<div id="bar">
  <span id="state">connecting...</span>
  <span id="disk" class="num"></span>
  <span id="sets" class="num"></span>
  <button id="arm">Arm</button><button id="disarm">Disarm</button>
  <input id="name" value="take1" title="recording name">
  <button id="start" class="rec">Start</button><button id="stop">Stop</button>
  <button id="event">Event</button>
</div>
<div id="msg"></div>
<div id="cams"></div>
<div id="summary" style="display:none"></div>
<script>
"use strict";
const params = new URLSearchParams(location.search);
const token = params.get("token") || "";
const q = (p) => p + (p.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token);
const $ = (id) => document.getElementById(id);
let cams = [], built = false, clicked = false, loaded = {};
function elapsed(s) {
  s = Math.floor(s);
  const h = Math.floor(s / 3600), m = Math.floor(s / 60) % 60, ss = s % 60;
  return (h ? h + ":" + String(m).padStart(2, "0") : m) + ":" + String(ss).padStart(2, "0");
}
function mb(x) { return x >= 1024 ? (x / 1024).toFixed(1) + " GB" : x.toFixed(0) + " MB"; }
async function control(line) {
  const r = await fetch(q("/api/control"), {method: "POST", body: line});
  const text = await r.text();
  $("msg").textContent = (r.ok ? "" : "refused: ") + text.trim();
  refresh();
  return r.ok;
}
$("arm").onclick = () => control("arm");
$("disarm").onclick = () => control("disarm");
$("start").onclick = () => control("start " + $("name").value);
$("stop").onclick = () => control("stop");
$("event").onclick = () => control("event " + $("name").value);
function build(status) {
  const box = $("cams");
  status.cameras.forEach((c, i) => {
    const d = document.createElement("div");
    d.className = "cam";
    d.innerHTML = `<h2>${c.name} <span class="num" style="font-weight:normal">(${c.id})</span></h2>
      <img id="img${i}" alt="camera ${c.name}">
      <canvas id="hist${i}" width="320" height="70"></canvas>
      <div class="num" id="info${i}"></div>
      <div>exposure µs <input id="exp${i}"> gain dB <input id="gain${i}" style="width:50px">
      <button id="apply${i}">Apply</button></div>`;
    box.appendChild(d);
    $("img" + i).onload = () => { loaded[c.name] = true; summarize(); };
    $("apply" + i).onclick = async () => {
      if ($("exp" + i).value) await control(`apply ${c.name} exposure_us ${$("exp" + i).value}`);
      if ($("gain" + i).value) await control(`apply ${c.name} gain_db ${$("gain" + i).value}`);
    };
  });
  built = true;
}
function summarize() {
  $("summary").textContent = "cameras shown: " + Object.keys(loaded).sort().join(",");
  $("summary").setAttribute("data-shown", Object.keys(loaded).length);
}
async function histogram(i) {
  const r = await fetch(q("/api/histogram?camera=" + i));
  if (!r.ok) return;
  const h = await r.json();
  const cv = $("hist" + i), g = cv.getContext("2d");
  g.fillStyle = "#111"; g.fillRect(0, 0, cv.width, cv.height);
  // Bars below a 15 px band for the text; the clipped bin (255) in red, scaled like the others.
  const peak = Math.max(1, ...h.bins.slice(0, 255)), top = 15, height = cv.height - top;
  for (let b = 0; b < 256; ++b) {
    const v = Math.min(1, h.bins[b] / peak);
    g.fillStyle = b === 255 ? "#ff3030" : "#c8c8c8";
    g.fillRect(b * cv.width / 256, top + height * (1 - v), cv.width / 256 + 0.5, height * v);
  }
  g.fillStyle = h.saturated_share > 0.001 ? "#ff5050" : "#9ad";
  g.font = "11px sans-serif";
  g.fillText("saturated " + (100 * h.saturated_share).toFixed(2) + "% (" + h.clipped_pixels +
             " px)", 4, 12);
}
async function refresh() {
  let s;
  try {
    const r = await fetch(q("/api/status"));
    if (!r.ok) { $("state").textContent = "error: " + (await r.text()); return; }
    s = await r.json();
  } catch (e) { $("state").textContent = "daemon gone"; return; }
  if (!built) build(s);
  const st = $("state");
  st.className = s.recording ? "rec" : "";
  st.textContent = !s.running ? "disarmed" : s.recording
      ? "RECORDING " + elapsed(s.recording_s) + " into " + s.recording_dir
      : "armed for " + elapsed(s.armed_s);
  $("disk").textContent = "disk " + mb(s.disk_free_mb) + " free" +
      (s.seconds_left >= 0 ? ", " + elapsed(s.seconds_left) + " left" : "");
  $("sets").textContent = `sets ${s.frame_sets.total} (${s.frame_sets.incomplete} incomplete)` +
      (s.recording ? `, recorded ${s.recorder.sets_recorded}, dropped ${s.recorder.sets_dropped}` : "");
  s.cameras.forEach((c, i) => {
    const stale = c.last_frame_age_s > 2 || (s.running && c.last_frame_age_s < 0);
    const missing = c.missing_by_frame_id + c.missing_by_timestamp + c.missed_triggers;
    $("info" + i).innerHTML =
        `<span class="${stale ? "bad" : ""}">${stale ? "no frames" : c.fps.toFixed(1) + " fps"}</span>` +
        `, ${c.megabytes_per_s.toFixed(1)} MB/s, ${c.frames} frames, ` +
        `<span class="${missing ? "warn" : ""}">${missing} missing</span>` +
        (c.missed_triggers ? ` (${c.missed_triggers} missed triggers)` : "") +
        (c.incomplete ? `, ${c.incomplete} incomplete` : "") +
        (c.error ? `<br><span class="bad">${c.error}</span>` : "");
    if (c.frames > 0) {
      $("img" + i).src = q(`/api/preview?camera=${i}&k=2&t=${Date.now()}`);
      histogram(i);
    }
  });
  if (!clicked && params.get("click") === "start") {
    clicked = true;
    if (params.get("name")) $("name").value = params.get("name");
    $("start").click();
  }
}
refresh();
setInterval(refresh, 1000);
</script></body></html>
)HTML";

bool Loopback(const std::string& host) {
  return host == "127.0.0.1" || host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
}

int CameraParam(const httplib::Request& req, const CaptureDaemon& daemon) {
  const std::string v = req.has_param("camera") ? req.get_param_value("camera") : "";
  const auto& cams = daemon.config().cameras;
  for (std::size_t c = 0; c < cams.size(); ++c)
    if (cams[c].name == v || std::to_string(c) == v) return static_cast<int>(c);
  throw InputError("no camera '" + v.substr(0, 32) + "'");
}

// The latest frame of a camera, or an InputError saying there is none yet.
Frame LatestFrame(const CaptureDaemon& daemon, int camera) {
  const std::shared_ptr<const FrameSet> set = daemon.LatestSet();
  if (!set || camera >= static_cast<int>(set->frames.size()) || !set->frames[camera])
    throw InputError("no frame from camera '" + daemon.config().cameras[camera].name + "' yet");
  return *set->frames[camera];
}

// Where the raw pixels sit at or above `full_scale`: 255 there, 0 elsewhere (full size).
cv::Mat ClippedMask(const Frame& f, int full_scale) {
  const int n = f.info.width * f.info.height;
  cv::Mat mask(f.info.height, f.info.width, CV_8UC1, cv::Scalar(0));
  const std::uint8_t* p = f.data->data();
  if (BytesPerPixel(f.info.pixel_format) == 2) {  // Mono16, Bayer 16
    for (int i = 0; i < n; ++i) {
      std::uint16_t v;
      std::memcpy(&v, p + 2 * i, 2);
      if (v >= full_scale) mask.data[i] = 255;
    }
  } else if (f.info.pixel_format == PixelFormat::kRgb8) {
    for (int i = 0; i < n; ++i)
      if (p[3 * i] >= full_scale || p[3 * i + 1] >= full_scale || p[3 * i + 2] >= full_scale)
        mask.data[i] = 255;
  } else {
    for (int i = 0; i < n; ++i)
      if (p[i] >= full_scale) mask.data[i] = 255;
  }
  return mask;
}

// The full scale of camera `camera`'s frame `f`: its wire format's, when it sent one.
int CameraFullScale(const CaptureDaemon& daemon, int camera, const Frame& f) {
  return FullScaleValue(f.info, daemon.camera_settings(camera).wire_format);
}

std::string PreviewPng(const Frame& f, int k, int full_scale) {
  std::vector<std::uint8_t> png;
  cv::imencode(".png", PreviewImage(f, k, full_scale, /*mark_clipped=*/true), png);
  return std::string(png.begin(), png.end());
}

}  // namespace

LiveViewOptions LiveViewOptions::Parse(const std::string& listen, const std::string& where) {
  LiveViewOptions o;
  std::string port = listen;
  const auto colon = listen.rfind(':');
  if (colon != std::string::npos) {
    o.host = listen.substr(0, colon);
    port = listen.substr(colon + 1);
  }
  char* end = nullptr;
  const long p = std::strtol(port.c_str(), &end, 10);
  if (port.empty() || *end != '\0' || p < 0 || p > 65535 || o.host.empty())
    throw InputError(where + ": '" + listen + "': use HOST:PORT or PORT (0: any free port)");
  o.port = static_cast<int>(p);
  return o;
}

cv::Mat PreviewImage(const Frame& f, int k, int full_scale, bool mark_clipped) {
  if (full_scale <= 0) full_scale = FullScaleValue(f.info, "");
  ImageU8 u8;
  ImageU16 u16;
  cv::Mat m;
  if (DecodeFrame(f, &u8, &u16) == 16) {
    cv::Mat(u16.height, u16.width, u16.channels == 3 ? CV_16UC3 : CV_16UC1, u16.pixels.data())
        .convertTo(m, CV_8U, 255.0 / full_scale);
  } else {
    m = cv::Mat(u8.height, u8.width, u8.channels == 3 ? CV_8UC3 : CV_8UC1, u8.pixels.data());
  }
  cv::Mat bgr = m;  // grey stays grey unless clipped pixels are drawn red
  if (m.channels() == 3)
    cv::cvtColor(m, bgr, cv::COLOR_RGB2BGR);
  else if (mark_clipped)
    cv::cvtColor(m, bgr, cv::COLOR_GRAY2BGR);
  k = std::max(1, k);
  const cv::Size size(std::max(1, bgr.cols / k), std::max(1, bgr.rows / k));
  cv::Mat small;
  cv::resize(bgr, small, size, 0, 0, cv::INTER_AREA);
  if (mark_clipped) {
    cv::Mat mask;
    cv::resize(ClippedMask(f, full_scale), mask, size, 0, 0, cv::INTER_AREA);
    small.setTo(cv::Scalar(0, 0, 255), mask > 0);  // clipped pixels in red
  }
  return small;
}

FrameHistogram HistogramOf(const Frame& f, int step, int full_scale) {
  FrameHistogram h;
  step = std::max(1, step);
  if (full_scale <= 0) full_scale = FullScaleValue(f.info, "");
  const int channels = f.info.pixel_format == PixelFormat::kRgb8 ? 3 : 1;
  const bool wide = BytesPerPixel(f.info.pixel_format) == 2;  // Mono16, Bayer 16
  const std::uint8_t* p = f.data ? f.data->data() : nullptr;
  if (!p) return h;
  for (int y = 0; y < f.info.height; y += step)
    for (int x = 0; x < f.info.width; x += step)
      for (int c = 0; c < channels; ++c) {
        const std::size_t i = (std::size_t(y) * f.info.width + x) * channels + c;
        if (wide) {
          std::uint16_t v;
          std::memcpy(&v, p + 2 * i, 2);
          ++h.bins[v >> 8];
          h.clipped += v >= full_scale;
        } else {
          ++h.bins[p[i]];
          h.clipped += p[i] >= full_scale;
        }
        ++h.sampled;
      }
  return h;
}

struct LiveViewServer::Impl {
  httplib::Server server;
};

LiveViewServer::LiveViewServer(CaptureDaemon* daemon, const LiveViewOptions& options)
    : impl_(std::make_unique<Impl>()), daemon_(daemon), options_(options) {
  if (!Loopback(options_.host) && !options_.allow_remote)
    throw InputError("live view: " + options_.host +
                     " is not loopback; set live_view_allow_remote: true (a token is then "
                     "required)");
  if (options_.allow_remote && options_.token.empty()) {
    std::random_device rd;
    char b[33];
    std::snprintf(b, sizeof b, "%08x%08x%08x%08x", rd(), rd(), rd(), rd());
    options_.token = b;
  }
  httplib::Server& s = impl_->server;
  s.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    ++requests_;
    if (options_.token.empty()) return httplib::Server::HandlerResponse::Unhandled;
    const std::string given = req.has_param("token") ? req.get_param_value("token")
                                                     : req.get_header_value("X-Flamerig-Token");
    if (given == options_.token) return httplib::Server::HandlerResponse::Unhandled;
    res.status = 403;
    res.set_content("a token is required (the url the daemon logged carries it)\n", "text/plain");
    return httplib::Server::HandlerResponse::Handled;
  });
  auto guarded = [](auto&& body) {
    return [body](const httplib::Request& req, httplib::Response& res) {
      try {
        body(req, res);
      } catch (const std::exception& e) {
        res.status = 400;
        res.set_content(std::string(e.what()) + "\n", "text/plain");
      }
    };
  };
  s.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(kPage, "text/html; charset=utf-8");
  });
  s.Get("/api/status", guarded([this](const httplib::Request&, httplib::Response& res) {
          res.set_content(daemon_->status().ToJson(), "application/json");
        }));
  s.Get("/api/preview", guarded([this](const httplib::Request& req, httplib::Response& res) {
          const int camera = CameraParam(req, *daemon_);
          int k = 4;
          if (req.has_param("k"))
            k = std::clamp(std::atoi(req.get_param_value("k").c_str()), 1, 64);
          res.set_header("Cache-Control", "no-store");
          const Frame f = LatestFrame(*daemon_, camera);
          res.set_content(PreviewPng(f, k, CameraFullScale(*daemon_, camera, f)), "image/png");
        }));
  s.Get("/api/histogram", guarded([this](const httplib::Request& req, httplib::Response& res) {
          const int camera = CameraParam(req, *daemon_);
          const Frame f = LatestFrame(*daemon_, camera);
          const FrameHistogram h = HistogramOf(f, 2, CameraFullScale(*daemon_, camera, f));
          nlohmann::json j;
          j["bins"] = h.bins;
          j["sampled"] = h.sampled;
          j["clipped_pixels"] = h.clipped;
          j["saturated_share"] = h.saturated_share();
          res.set_content(j.dump(), "application/json");
        }));
  s.Post("/api/control", guarded([this](const httplib::Request& req, httplib::Response& res) {
           std::string line = req.body;
           while (!line.empty() && (line.back() == '\n' || line.back() == '\r')) line.pop_back();
           ControlReply r;
           if (line.rfind("shutdown", 0) == 0) {
             r.body = "shutdown is not offered to the browser; use flamerig ctl\n";
           } else {
             r = HandleControlRequest(*daemon_, line, nullptr);
           }
           res.status = r.ok ? 200 : 400;
           res.set_content(r.body, "text/plain");
         }));
  const int bound = options_.port == 0
                        ? s.bind_to_any_port(options_.host)
                        : (s.bind_to_port(options_.host, options_.port) ? options_.port : -1);
  if (bound < 0)
    throw IoError("live view: cannot listen on " + options_.host + ":" +
                  std::to_string(options_.port));
  port_ = bound;
  thread_ = std::thread([this] { impl_->server.listen_after_bind(); });
  for (int i = 0; i < 200 && !impl_->server.is_running(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
}

LiveViewServer::~LiveViewServer() {
  impl_->server.stop();
  if (thread_.joinable()) thread_.join();
}

std::string LiveViewServer::url() const {
  const std::string host = options_.host.find(':') != std::string::npos
                               ? "[" + options_.host + "]"
                               : (options_.host == "0.0.0.0" ? "127.0.0.1" : options_.host);
  return "http://" + host + ":" + std::to_string(port_) + "/" +
         (options_.token.empty() ? "" : "?token=" + options_.token);
}

}  // namespace flamerig
