// A memory hint shared by the factorisations' large buffers.
#pragma once

#include <sys/mman.h>

#include <cstddef>
#include <cstdint>

namespace modal_mass_spring
{

// Asks the kernel to back [data, data + bytes) with 2 MB pages where it can: a large buffer written
// once (a factor, the Lanczos vectors) otherwise takes a page fault every 4 kB. A hint only; nothing
// changes where it is refused.
inline void adviseHugePages(void* data, std::size_t bytes)
{
  constexpr std::uintptr_t huge = std::uintptr_t{2} << 20;
  const std::uintptr_t begin = (reinterpret_cast<std::uintptr_t>(data) + huge - 1) & ~(huge - 1);
  const std::uintptr_t end = (reinterpret_cast<std::uintptr_t>(data) + bytes) & ~(huge - 1);
  if (end > begin)
    madvise(reinterpret_cast<void*>(begin), end - begin, MADV_HUGEPAGE);
}

}  // namespace modal_mass_spring
