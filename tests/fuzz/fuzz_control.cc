// Control API requests (acquisition/control.h) against a daemon with two simulated cameras:
// HandleControlRequest never throws; every request gets a reply.
#include <atomic>
#include <memory>
#include <string>

#include "acquisition/capture.h"
#include "acquisition/control.h"
#include "tests/fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static flamerig::SystemClock clock;
  static flamerig::SimTriggerBus bus;
  static std::unique_ptr<flamerig::CaptureDaemon> daemon = [] {
    const std::string yaml =
        "data_dir: " + (flamerig_fuzz::Dir() / "rec").string() +
        "\nsync: software-trigger\ntrigger_rate_hz: 10\npretrigger_seconds: 0\n"
        "cameras:\n  - {name: cam0, width: 32, height: 24}\n"
        "  - {name: cam1, width: 32, height: 24}\n";
    const flamerig::CaptureConfig config = flamerig::CaptureConfig::Parse(yaml, "fuzz");
    auto d = std::make_unique<flamerig::CaptureDaemon>(
        config, flamerig::MakeCameras(config, {&clock, &bus}), &clock, &bus);
    d->Start();
    return d;
  }();
  std::atomic<bool> shutdown{false};
  const std::string line(reinterpret_cast<const char*>(data), size);
  const flamerig::ControlReply r = flamerig::HandleControlRequest(*daemon, line, &shutdown);
  if (!r.ok && r.body.empty()) __builtin_trap();  // an error always says why
  return 0;
}
