// AllocateHugePageBacked and HugePageAllocator: every block aligned to a cache line below 2 MiB
// and to 2 MiB from there, whatever malloc would have given (it puts blocks of 128 KiB and more
// 16 bytes past a page), writable to its last byte, and freed.
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <vector>

#include "core/memory.h"

namespace flamerig {
namespace {

std::uintptr_t Address(const void* p) { return reinterpret_cast<std::uintptr_t>(p); }

TEST(HugePageBacked, BlocksAreAlignedToACacheLineOrAHugePage) {
  // Sizes around malloc's own thresholds (its mmap threshold starts at 128 KiB) and odd ones.
  for (std::size_t bytes :
       {std::size_t(0), std::size_t(1), std::size_t(17), std::size_t(4095), std::size_t(150000),
        std::size_t(128 << 10), std::size_t(1 << 20), (std::size_t(2) << 20) - 1,
        std::size_t(2) << 20, (std::size_t(5) << 20) + 3}) {
    void* p = AllocateHugePageBacked(bytes);
    ASSERT_NE(p, nullptr) << bytes;
    const std::uintptr_t alignment = bytes >= (std::size_t(2) << 20) ? (std::size_t(2) << 20) : 64;
    EXPECT_EQ(Address(p) % alignment, 0u) << bytes << " bytes at " << p;
    if (bytes > 0) std::memset(p, 0xab, bytes);  // the whole block is ours (ASan would object)
    FreeHugePageBacked(p);
  }
}

TEST(HugePageBacked, VectorsOfTheAllocatorStartOnACacheLine) {
  // The renderer's kelvin table: rows of 24 floats read 8 at a time.
  for (std::size_t floats : {std::size_t(24), std::size_t(37'000), std::size_t(40'000)}) {
    std::vector<float, HugePageAllocator<float>> table(floats, 1.0f);
    EXPECT_EQ(Address(table.data()) % 64, 0u) << floats;
    table.resize(2 * floats, 2.0f);  // reallocation keeps the alignment
    EXPECT_EQ(Address(table.data()) % 64, 0u) << floats;
    EXPECT_EQ(table.back(), 2.0f);
  }
}

}  // namespace
}  // namespace flamerig
