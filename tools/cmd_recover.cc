// `flamerig recover`: a damaged or interrupted recording's indexes rebuilt from its data files
// (acquisition/recording.h, RebuildIndexes).
#include <memory>
#include <string>

#include "acquisition/recording.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddRecover(CLI::App* command) {
  auto dir = std::make_shared<std::string>();
  command->footer(
      "Rebuild a recording's camNN.index and sets.index from its data files: frames behind a\n"
      "damaged or missing index, set records that are corrupt or gone, and the sets an\n"
      "interrupted recorder never committed whose frames all reached the disk. Every frame's\n"
      "pixels are checked against their CRC and each damaged one is listed. The data files and\n"
      "metadata.yaml are not modified; the old index files are kept in\n"
      "DIR/replaced_indexes_<UTC time>/. Exit status 1 when frames are lost or damaged.\n"
      "export and run salvage a damaged recording without this; recover makes it fast and clean.");
  command->add_option("--recording", *dir, "The recording's folder")->required()->type_name("DIR");
  return [dir](Context&) {
    const RecoveryReport r = RebuildIndexes(*dir);
    for (const auto& note : r.notes) Log().warn("recover: {}", note);
    Log().info(
        "recover: {}: {} frame sets ({} rebuilt from their frames, {} uncommitted taken in), "
        "{} frame(s) lost, {} damaged, {} bytes of damaged data skipped, {} camera index(es) "
        "rebuilt from the data files",
        *dir, r.sets, r.rebuilt_sets, r.added_sets, r.lost_frames, r.corrupt_frames,
        r.damaged_bytes, r.rebuilt_indexes.size());
    return r.lost_frames + r.corrupt_frames > 0 ? kExitError : kExitOk;
  };
}

}  // namespace flamerig::cli
