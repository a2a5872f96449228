// `flamerig export-volume`: a fitted or reconstructed .vdb as a table (CSV, NumPy, HDF5) with
// coordinates in metres (pipeline/volume_export.h).
#include <cstdio>
#include <memory>

#include "pipeline/volume_export.h"
#include "tomography/vdb_io.h"
#include "tools/cli.h"

namespace flamerig::cli {

Runner AddExportVolume(CLI::App* command) {
  struct Options {
    std::string volume, out;
    bool dense = false;
  };
  auto o = std::make_shared<Options>();
  command->footer(
      "Write a volume (.vdb from fit, run or reconstruct) as a table, one row per voxel: i, j, k,\n"
      "the voxel centre x_m, y_m, z_m in the rig frame (metres), then temperature_k,\n"
      "density_per_m3, temperature_sigma_k, density_sigma, determined, soot_volume_fraction and\n"
      "emission_r/g/b where\n"
      "the volume has them. The format follows --out's extension: .csv, .npy (a NumPy structured\n"
      "array: numpy.load(F)[\"temperature_k\"]) or .h5 (one dataset per column, with units; the\n"
      "grid and metadata as attributes). CSV and NumPy get F.json beside them (frame.npy.json)\n"
      "with the grid, units and metadata. Rows: the voxels with medium, or with --dense every "
      "voxel (a column\n"
      "then reshapes to (nz, ny, nx)).");
  command->add_option("--volume", o->volume, "The volume to export")
      ->required()
      ->type_name("V.vdb");
  command->add_option("--out", o->out, "The table: .csv, .npy or .h5")
      ->required()
      ->type_name("F.csv|F.npy|F.h5");
  command->add_flag("--dense", o->dense, "Every voxel of the grid, not only those with medium");
  return [o](Context&) {
    VolumeTableFormatOf(o->out);  // a wrong extension is refused before the volume is read
    VolumeExportOptions options;
    options.dense = o->dense;
    options.source = o->volume;
    const VolumeExportSummary s = ExportVolumeTable(ReadVdb(o->volume), o->out, options);
    std::string columns;
    for (const auto& c : s.columns) columns += (columns.empty() ? "" : ", ") + c;
    std::printf("export-volume: %zu voxels x %zu columns (%s)\n", s.rows, s.columns.size(),
                columns.c_str());
    for (const auto& f : s.files) std::printf("  %s\n", f.c_str());
    return kExitOk;
  };
}

}  // namespace flamerig::cli
