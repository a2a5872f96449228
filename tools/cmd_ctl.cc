// `flamerig ctl`: one request to a running capture daemon (acquisition/control.h).
#include <cstdio>
#include <memory>

#include "acquisition/capture.h"
#include "acquisition/control.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddCtl(CLI::App* command) {
  struct Options {
    std::string config, endpoint, out;
    std::vector<std::string> request;
    bool json = false;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Talk to a running daemon: status (a table; --json for scripts, `status yaml` for YAML),\n"
      "cameras, arm, disarm, configure CAMERA KEY VALUE, start NAME, stop, event NAME,\n"
      "preview CAMERA [K] (PNG to --out), shutdown.");
  command->add_option("--config", o->config, "The daemon's capture config (for its endpoint)")
      ->type_name("RIG.yaml");
  command->add_option("--endpoint", o->endpoint, "The daemon's control endpoint")
      ->type_name("unix:PATH|tcp:HOST:PORT");
  command->add_option("--out", o->out, "Write the reply (a preview PNG) here")->type_name("FILE");
  command->add_flag("--json", o->json, "status as JSON, for scripts (default: a table for people)");
  command->add_option("request", o->request, "The request and its words")
      ->required()
      ->type_name("REQUEST...");
  return [o](Context&) {
    std::string endpoint = o->endpoint;
    if (endpoint.empty()) {
      if (o->config.empty()) throw UsageError("give --config or --endpoint");
      endpoint = CaptureConfig::Load(o->config).control;
    }
    std::string line;
    for (const auto& w : o->request) line += (line.empty() ? "" : " ") + w;
    // `status` for people unless asked otherwise; `status yaml` gives the daemon's YAML.
    if (line == "status") line = o->json ? "status json" : "status table";
    if (o->json && line != "status json") throw UsageError("--json is for `status` only");
    const ControlReply r = ControlRequest(endpoint, line);
    if (!r.ok) {
      Log().error("flamerig ctl: the daemon says: {}", r.body);
      return kExitError;
    }
    if (!o->out.empty())
      WriteFileAtomically(o->out, r.body);
    else
      std::fwrite(r.body.data(), 1, r.body.size(), stdout);
    return kExitOk;
  };
}

}  // namespace flamerig::cli
