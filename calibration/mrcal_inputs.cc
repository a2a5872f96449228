#include "calibration/mrcal_inputs.h"

#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <stdexcept>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/npy.h"
#include "core/read_file.h"

namespace flamerig {
namespace {

void PutLe(std::string* s, std::uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) s->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

}  // namespace

namespace internal {

std::string Base85Encode(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz!#$%&()*+-;<=>?@^_`{|}~";
  std::string out;
  out.reserve(bytes.size() / 4 * 5 + 5);
  for (std::size_t i = 0; i < bytes.size(); i += 4) {
    const std::size_t n = std::min<std::size_t>(4, bytes.size() - i);
    std::uint32_t word = 0;  // big-endian, a short last chunk padded with zeros
    for (std::size_t k = 0; k < 4; ++k)
      word = (word << 8) | (k < n ? static_cast<unsigned char>(bytes[i + k]) : 0u);
    char chunk[5];
    for (int k = 4; k >= 0; --k) {
      chunk[k] = kAlphabet[word % 85];
      word /= 85;
    }
    out.append(chunk, n + 1);  // a short chunk keeps n + 1 characters
  }
  return out;
}

namespace {

// A .npy file: the shared header (core/npy.h), then the data.
std::string Npy(const NpyMember& m) { return NpyHeader("'" + m.descr + "'", m.shape) + m.data; }

std::string Deflate(const std::string& in) {
  z_stream z{};
  if (deflateInit2(&z, Z_DEFAULT_COMPRESSION, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY) != Z_OK)
    throw std::runtime_error("npz: zlib's deflate could not start");
  if (in.size() > 0xffffffffu) {  // zlib's counts are 32-bit
    deflateEnd(&z);
    throw DataError("npz: a member larger than 4 GiB, which this writer cannot store");
  }
  std::string out(deflateBound(&z, in.size()), '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  const int rc = deflate(&z, Z_FINISH);
  out.resize(z.total_out);
  deflateEnd(&z);
  if (rc != Z_STREAM_END) throw std::runtime_error("npz: zlib's deflate failed");
  return out;
}

}  // namespace

std::string WriteNpz(const std::vector<NpyMember>& members) {
  std::string zip, directory;
  for (const NpyMember& m : members) {
    const std::string name = m.name + ".npy";
    const std::string raw = Npy(m);
    const std::string packed = Deflate(raw);
    const std::uint32_t crc =
        crc32(0L, reinterpret_cast<const Bytef*>(raw.data()), static_cast<uInt>(raw.size()));
    const std::size_t offset = zip.size();
    // No zip64: every size and offset must fit 32 bits (numpy would read a larger file, this
    // writer would not write it correctly).
    if (raw.size() > 0xffffffffu || packed.size() > 0xffffffffu || offset > 0xffffffffu)
      throw DataError("npz: " + name + " is larger than 4 GiB, which this writer cannot store");
    // The fields the local header and the central directory entry share: version 2.0 needed, no
    // flags, deflated, 1980-01-01 00:00, the CRC and sizes, the name's length, no extra field.
    auto shared = [&](std::string* to) {
      for (int v : {20, 0, 8, 0, 0x21}) PutLe(to, static_cast<std::uint64_t>(v), 2);
      PutLe(to, crc, 4);
      PutLe(to, packed.size(), 4);
      PutLe(to, raw.size(), 4);
      PutLe(to, name.size(), 2);
      PutLe(to, 0, 2);
    };
    PutLe(&zip, 0x04034b50, 4);  // local file header
    shared(&zip);
    zip += name;
    zip += packed;
    PutLe(&directory, 0x02014b50, 4);  // its central directory entry
    PutLe(&directory, 20, 2);          // made by version 2.0
    shared(&directory);
    PutLe(&directory, 0, 2);  // comment
    PutLe(&directory, 0, 2);  // disk
    PutLe(&directory, 0, 2);  // internal attributes
    PutLe(&directory, 0, 4);  // external attributes
    PutLe(&directory, offset, 4);
    directory += name;
  }
  const std::size_t directory_offset = zip.size();
  if (directory_offset + directory.size() > 0xffffffffu || members.size() > 0xffff)
    throw DataError("npz: larger than 4 GiB or 65535 members, which this writer cannot store");
  zip += directory;
  PutLe(&zip, 0x06054b50, 4);
  PutLe(&zip, 0, 2);
  PutLe(&zip, 0, 2);
  PutLe(&zip, members.size(), 2);
  PutLe(&zip, members.size(), 2);
  PutLe(&zip, directory.size(), 4);
  PutLe(&zip, directory_offset, 4);
  PutLe(&zip, 0, 2);
  return zip;
}

}  // namespace internal

namespace {

using internal::NpyMember;

template <typename T>
std::string Bytes(const T* values, std::size_t n) {
  if (n == 0) return {};
  return std::string(reinterpret_cast<const char*>(values), n * sizeof(T));
}
NpyMember Doubles(const std::string& name, std::vector<std::size_t> shape, const double* v,
                  std::size_t n) {
  return {name, "<f8", std::move(shape), Bytes(v, n)};
}
NpyMember Ints(const std::string& name, std::vector<std::size_t> shape, const int32_t* v,
               std::size_t n) {
  return {name, "<i4", std::move(shape), Bytes(v, n)};
}
NpyMember Bool(const std::string& name, bool b) { return {name, "|b1", {}, std::string(1, b)}; }
// A str scalar: numpy's '<U' dtype, four bytes (UTF-32 little-endian) a character; '' is None.
NpyMember Text(const std::string& name, const std::string& text) {
  std::string data;
  for (char ch : text) {
    // One byte a code point: ASCII only (a lens model's name is).
    if (static_cast<unsigned char>(ch) >= 0x80)
      throw DataError("mrcal optimization inputs: '" + name + "' is not ASCII");
    PutLe(&data, static_cast<unsigned char>(ch), 4);
  }
  if (text.empty()) data.assign(4, '\0');
  return {name, "<U" + std::to_string(std::max<std::size_t>(1, text.size())), {}, data};
}

}  // namespace

std::string SerializeMrcalOptimizationInputs(const MrcalProblem& p) {
  const std::size_t cams = static_cast<std::size_t>(p.num_cameras);
  const std::size_t obs = p.indices.size();
  const std::size_t w = static_cast<std::size_t>(p.board_width),
                    h = static_cast<std::size_t>(p.board_height);
  if (p.intrinsics.size() != cams * static_cast<std::size_t>(p.num_params) ||
      p.extrinsics.size() + 1 != cams || p.imagersizes.size() != cams ||
      p.observations.size() != obs * h * w * 3)
    throw DataError("mrcal optimization inputs: inconsistent sizes");
  std::vector<NpyMember> m;
  m.push_back(Text("lensmodel", p.lensmodel));
  m.push_back(Doubles("intrinsics", {cams, static_cast<std::size_t>(p.num_params)},
                      p.intrinsics.data(), p.intrinsics.size()));
  m.push_back(Doubles("extrinsics_rt_fromref", {cams - 1, 6},
                      p.extrinsics.empty() ? nullptr : p.extrinsics[0].data(), 6 * (cams - 1)));
  m.push_back(Doubles("frames_rt_toref", {p.frames.size(), 6},
                      p.frames.empty() ? nullptr : p.frames[0].data(), 6 * p.frames.size()));
  m.push_back(Text("points", ""));
  m.push_back(Doubles("calobject_warp", {2}, p.calobject_warp.data(), 2));
  m.push_back(Ints("indices_frame_camintrinsics_camextrinsics", {obs, 3},
                   obs ? p.indices[0].data() : nullptr, 3 * obs));
  m.push_back(
      Doubles("observations_board", {obs, h, w, 3}, p.observations.data(), p.observations.size()));
  m.push_back(Text("indices_point_camintrinsics_camextrinsics", ""));
  m.push_back(Text("observations_point", ""));
  m.push_back(Doubles("calibration_object_spacing", {}, &p.spacing_m, 1));
  m.push_back(Ints("imagersizes", {cams, 2}, p.imagersizes[0].data(), 2 * cams));
  m.push_back(Bool("do_optimize_intrinsics_core", p.optimize_intrinsics_core));
  m.push_back(Bool("do_optimize_intrinsics_distortions", p.optimize_intrinsics_distortions));
  m.push_back(Bool("do_optimize_extrinsics", p.optimize_extrinsics));
  m.push_back(Bool("do_optimize_frames", p.optimize_frames));
  m.push_back(Bool("do_optimize_calobject_warp", p.optimize_calobject_warp));
  m.push_back(Bool("do_apply_regularization", p.apply_regularization));
  m.push_back(Bool("do_apply_outlier_rejection", p.apply_outlier_rejection));
  m.push_back(Bool("verbose", false));
  return internal::Base85Encode(internal::WriteNpz(m));
}

void AddCameraModelFields(const std::string& cameramodel_path, const std::string& fields) {
  std::string text = ReadFile(cameramodel_path);
  const std::size_t brace = text.rfind('}');
  if (brace == std::string::npos)
    throw DataError(cameramodel_path + ": not a camera model (no closing brace)");
  text.insert(brace, fields);
  WriteFileAtomically(cameramodel_path, text);
}

void AddMrcalOptimizationInputs(const std::string& cameramodel_path, const std::string& serialized,
                                int icam_intrinsics) {
  AddCameraModelFields(
      cameramodel_path,
      "    'icam_intrinsics': " + std::to_string(icam_intrinsics) +
          ",\n"
          "    # The solve's inputs, as mrcal-calibrate-cameras stores them (numpy "
          ".npz, base85): mrcal's\n"
          "    # tools compute the projection uncertainty from them.\n"
          "    'optimization_inputs': b'" +
          serialized + "',\n");
}

}  // namespace flamerig
