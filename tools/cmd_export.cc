// `flamerig export`: a recording's (or StreamPix sequences') frame sets as PNG images
// (pipeline/export.h).
#include <cstdio>
#include <memory>

#include "acquisition/recording.h"
#include "pipeline/export.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddExport(CLI::App* command) {
  struct Options {
    std::string recording, seq, names, out;
    std::int64_t first = -1, count = -1;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Write a recording's (or StreamPix sequences') frame sets as DIR/frame_NNNNNN/<camera>.png\n"
      "(the layout reconstruct and fit read) and DIR/sets.csv; reports what a recovered recording\n"
      "left out. A damaged frame is skipped and reported; the exit status is then 1.");
  command->add_option("--recording", o->recording, "A flamerig recording")->type_name("DIR");
  command->add_option("--seq", o->seq, "StreamPix sequences, one per camera")
      ->type_name("A.seq,B.seq");
  command->add_option("--names", o->names, "Camera names of the sequences (default: file stems)")
      ->type_name("CAM,CAM");
  command->add_option("--out", o->out, "Output folder")->required()->type_name("DIR");
  command->add_option("--first", o->first, "First frame set")
      ->type_name("N")
      ->check(Whole(0, kMaxFrames));
  command->add_option("--count", o->count, "How many frame sets")
      ->type_name("N")
      ->check(Whole(1, kMaxFrames));
  return [o](Context& context) {
    if (o->recording.empty() == o->seq.empty()) throw UsageError("give --recording or --seq");
    context.StopOnSignals();
    ExportOptions options;
    if (o->first >= 0) options.first = static_cast<std::size_t>(o->first);
    if (o->count >= 0) options.count = static_cast<std::size_t>(o->count);
    ExportSummary s;
    if (!o->seq.empty()) {
      s = ExportStreamPix(SplitList(o->seq), SplitList(o->names), o->out, options,
                          context.Progress());
    } else {
      const Recording rec = Recording::Open(o->recording);
      for (const auto& note : rec.recovery().notes)
        Log().warn("export: recovered recording: {}", note);
      s = ExportRecording(o->recording, o->out, options, context.Progress());
    }
    for (const auto& f : s.failed) Log().error("export: skipped {}", f);
    for (const auto& n : s.notes) Log().warn("export: {}", n);
    if (s.event_set >= 0)
      Log().info("export: the event's trigger falls before set {}", s.event_set);
    Log().info("export: {} frame sets, {} images, {} camera frames missing, {} damaged", s.sets,
               s.images, s.missing_frames, s.failed.size());
    if (s.cancelled) return kExitCancelled;
    return s.failed.empty() ? kExitOk : kExitError;
  };
}

}  // namespace flamerig::cli
