// Steps 1-2 of the row loop (design notes in extract.cc): the saturating difference of the laser
// channel, and the 64-pixel groups that hold a pixel >= threshold, compacted into (start, bit mask) pairs
// without a branch. Nothing else is read per pixel, so a row without the laser costs two loads and five
// vector instructions per 16 pixels and one compaction per 64 (the loop runs at the memory-bandwidth
// bound, laser_bench BM_RowPassOnly). A width that is not a multiple of 16 ends with one overlapping
// block whose already-seen bits are cleared.
#include "extract_steps.h"
#include "kernels.h"

namespace rotoscan::laser::detail {

int RowPass(const uint8_t* a, const uint8_t* b, int cols, int threshold, bool avx2, uint8_t* d, int* starts,
            uint64_t* masks) {
  int count = 0;
  int i0 = 0;
#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
  if (avx2) count = RowGroupsAvx2(a, b, d, cols, threshold, starts, masks, &i0);
#else
  (void)avx2;
#endif
#if defined(__SSE2__)
  count = sse2::RowGroups(a, b, d, cols, threshold, starts, masks, count, &i0);
#endif
  // The portable path (and images narrower than 16 pixels).
  return scalar::RowGroups(a, b, d, cols, threshold, starts, masks, count, &i0);
}

}  // namespace rotoscan::laser::detail
