// A fitted (or reconstructed) volume as a table a researcher can load without OpenVDB:
// `flamerig export-volume`. One row per voxel, one column per quantity:
//
//   i, j, k            int32    the voxel's index in the grid (tomography/volume.h)
//   x_m, y_m, z_m      float64  its centre in the rig frame, metres
//   temperature_k      float32  kelvin                                  (when the volume has it)
//   density_per_m3     float32  soot particles per m^3                  (when the volume has it)
//   temperature_sigma_k float32 the fit's one-sigma temperature error, K (when it has it)
//   density_sigma      float32  the sigma of ln(density): 0.1 is ~10%   (when it has it)
//   determined         float32  1 where the images determine the voxel  (when it has it)
//   soot_volume_fraction float32 m^3 of soot per m^3 (absorption.h)     (a soot fit, a truth)
//   emission_r/g/b     float32  linear emission, the renderer's units   (a reconstruction)
//
// The field values are the .vdb's floats, exactly (CSV prints 9 significant digits, which read
// back to the same float). Rows: the voxels with medium (density > 0; for a volume without density,
// those whose temperature or emission is not 0), in the grid's flat order (x fastest, then y, then
// z); `dense` writes every voxel of the grid instead, so that a column reshapes to (nz, ny, nx).
//
// Formats, chosen by the file's extension:
//   .csv  RFC 4180 with a header row of the column names above; with PATH.json beside it.
//   .npy  NumPy's format 1.0, a structured array of the columns above (numpy.load(PATH)["x_m"]);
//         with PATH.json beside it.
//   .h5   HDF5: one 1-D dataset per column at the root, each with a "units" attribute; the grid
//         (grid_dims, grid_origin_m, grid_voxel_size_m), source and row selection as attributes
//         of the root, the volume's metadata as attributes of the group /metadata (h5py, HDFView,
//         MATLAB).
// PATH.json (the table's whole name and ".json": frame0.npy.json): the source file, the grid (dims,
// origin_m, the min corner of the box, and voxel_size_m), the row selection, each column's units,
// and the volume's metadata (exposure, absorption model, ...).
//
// Every file is written under a temporary name and renamed (core/atomic_file.h).
#ifndef FLAMERIG_PIPELINE_VOLUME_EXPORT_H_
#define FLAMERIG_PIPELINE_VOLUME_EXPORT_H_

#include <cstddef>
#include <string>
#include <vector>

#include "tomography/volume.h"

namespace flamerig {

enum class VolumeTableFormat { kCsv, kNpy, kHdf5 };

// From a path's extension (.csv, .npy, .h5 or .hdf5); throws InputError naming the path otherwise.
VolumeTableFormat VolumeTableFormatOf(const std::string& path);

struct VolumeExportOptions {
  bool dense = false;  // every voxel of the grid, not only those with medium
  std::string source;  // what the volume was read from, for the metadata
};

struct VolumeExportSummary {
  std::size_t rows = 0;
  std::vector<std::string> columns;
  std::vector<std::string> files;  // the table, and its .json where the format needs one
};

// Writes `volume` as a table at `path` in the format of its extension. Throws InputError for an
// invalid volume or one with no field, IoError naming the path when it cannot be written.
VolumeExportSummary ExportVolumeTable(const FireVolume& volume, const std::string& path,
                                      const VolumeExportOptions& options = {});

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_VOLUME_EXPORT_H_
