// Reading and writing fire volumes as OpenVDB files, so that Blender, Houdini and OpenVDB's own
// tools (vdb_print, vdb_view) read flamerig's output.
//
// Grids written (only those present in the FireVolume):
//   temperature  FloatGrid, kelvin                    (background 0)
//   density      FloatGrid, particles per m^3         (background 0)
//   emission     Vec3SGrid, linear RGB emission       (background 0)
// and a fit's: temperature_sigma (K), density_sigma (of ln density), determined (1 or 0), and
// soot_volume_fraction (m^3 of soot per m^3) when the absorption model is soot.
// Only voxels whose value differs from the background are stored (active). Each grid's transform
// maps index (i, j, k) to the voxel centre in the rig frame, metres: world = (i, j, k) * voxel_size
// + origin + voxel_size / 2, so the volume lands where the rig put it. The grid's dims are stored
// as grid metadata "flamerig_dims" so that a round trip restores the full lattice, including empty
// borders; files from other programs fall back to the active voxels' bounding box.
// FireVolume metadata become file-level metadata (numbers as double, text as string).
#ifndef FLAMERIG_TOMOGRAPHY_VDB_IO_H_
#define FLAMERIG_TOMOGRAPHY_VDB_IO_H_

#include <cstddef>
#include <string>

#include "tomography/volume.h"

namespace flamerig {

// Validates `volume` and writes it. Throws InputError (bad volume) or IoError naming the path
// (I/O failure). Writes to a temporary name beside it and renames (core/atomic_file.h), so a crash
// never leaves a half-written file under the final name.
void WriteVdb(const std::string& path, const FireVolume& volume);

// Reads the grids named above (any subset; at least one of temperature, density and emission must
// exist).
// Throws InputError for a missing file, DataError naming the path and the problem: not a VDB
// file, no known grid, a non-linear or rotated transform, grids whose transforms disagree, or a
// lattice whose dense fields need more than `max_bytes` (0: this machine's physical memory,
// core/memory.h's PhysicalMemoryBytes). The
// fields are dense over the lattice that flamerig_dims declares, so a damaged or hostile file of a
// few hundred bytes can state 2^31 voxels: it is refused with the sizes, not killed by the kernel.
FireVolume ReadVdb(const std::string& path, std::size_t max_bytes = 0);

}  // namespace flamerig

#endif  // FLAMERIG_TOMOGRAPHY_VDB_IO_H_
