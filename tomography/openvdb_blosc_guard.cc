// A bounds-checked replacement for OpenVDB 10.0's io::bloscFromStream, the function that reads one
// blosc chunk of a grid's values from a .vdb file.
//
// Why: in the OpenVDB that Debian 12 ships (10.0.1) that function reads an uncompressed chunk of
// the size the file states into a buffer of the size the grid expects, and only then compares the
// two; a damaged or hostile .vdb overflows the heap (found by fuzz_vdb under ASan: a write of 5431
// bytes into 5360). It also allocates whatever size a compressed chunk states (terabytes in the
// fuzzer's inputs). Later OpenVDB releases check the uncompressed size first.
//
// How: this definition, in the same versioned namespace, is linked into every flamerig binary and
// takes precedence over the shared library's (ELF symbol interposition: libopenvdb is not linked
// -Bsymbolic, so both our own template instantiations of io::readCompressedValues and the library's
// internal calls reach it). It reads the same format and checks every size before it is used:
//   - a chunk's stated size is read first (8 bytes, little-endian int64); <= 0 means uncompressed;
//   - an uncompressed chunk must be exactly the expected size, checked before reading;
//   - a compressed chunk can be at most the expected size plus blosc's header
//     (BLOSC_MAX_OVERHEAD: blosc never expands data by more), checked before allocating; its
//     header is validated against its length (blosc_cbuffer_validate) and must decompress to
//     exactly the expected size.
// Errors are openvdb::RuntimeError, as OpenVDB's own, which ReadVdb turns into an error naming the
// file. tests/fuzz/regressions/vdb holds the input that overflowed; the unit test
// Vdb.AHeapOverflowFoundByFuzzingIsAnError reads it.
#include <blosc.h>
#include <openvdb/Exceptions.h>
#include <openvdb/io/Compression.h>
#include <openvdb/version.h>

#include <cstdint>
#include <istream>
#include <limits>
#include <memory>

namespace openvdb {
OPENVDB_USE_VERSION_NAMESPACE
namespace OPENVDB_VERSION_NAME {
namespace io {

void bloscFromStream(std::istream& is, char* data, size_t numBytes) {
  std::int64_t stated = 0;
  is.read(reinterpret_cast<char*>(&stated), sizeof stated);
  if (!is.good()) OPENVDB_THROW(RuntimeError, "stream failure reading the size of a blosc chunk");
  if (stated <= 0) {
    // Uncompressed: the size must be the expected one before a byte is read.
    if (stated == std::numeric_limits<std::int64_t>::min() ||
        static_cast<std::uint64_t>(-stated) != numBytes)
      OPENVDB_THROW(RuntimeError, "expected an uncompressed chunk of "
                                      << numBytes << " bytes, the file states " << -stated);
    if (data == nullptr) {
      is.seekg(-stated, std::ios_base::cur);
    } else {
      is.read(data, -stated);
      if (is.gcount() != -stated) OPENVDB_THROW(RuntimeError, "the file ends inside a chunk");
    }
    return;
  }
  if (static_cast<std::uint64_t>(stated) > numBytes + BLOSC_MAX_OVERHEAD)
    OPENVDB_THROW(RuntimeError, "a compressed chunk of " << stated << " bytes for " << numBytes
                                                         << " bytes of values");
  if (data == nullptr) {
    is.seekg(stated, std::ios_base::cur);
    return;
  }
  std::unique_ptr<char[]> chunk(new char[static_cast<std::size_t>(stated)]);
  is.read(chunk.get(), stated);
  if (is.gcount() != stated) OPENVDB_THROW(RuntimeError, "the file ends inside a chunk");
  std::size_t holds = 0;
  if (blosc_cbuffer_validate(chunk.get(), static_cast<std::size_t>(stated), &holds) != 0 ||
      holds != numBytes)
    OPENVDB_THROW(RuntimeError, "a damaged blosc chunk (expected " << numBytes << " bytes)");
  const int got = blosc_decompress_ctx(chunk.get(), data, numBytes, /*numinternalthreads=*/1);
  if (got < 0 || static_cast<std::size_t>(got) != numBytes)
    OPENVDB_THROW(RuntimeError, "blosc decompressed " << got << " bytes, expected " << numBytes);
}

}  // namespace io
}  // namespace OPENVDB_VERSION_NAME
}  // namespace openvdb
