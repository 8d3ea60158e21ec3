// The extractor's SSSE3 kernel, dispatched at run time (kernels.h: used when the CPU has SSSE3 and
// internal::AllowVectorExtensions allows it): a color row's laser channel pulled out by byte shuffles.
// Elsewhere the row loop (extract.cc) deinterleaves bands of rows with cv::split.
#include "kernels.h"

#if defined(ROTOSCAN_HAVE_SSSE3_PATH)
#include <tmmintrin.h>

#include <cstdint>

namespace rotoscan::laser::detail {

// dst[i] = src[i * channels + channel] for i < pixels, channels 3 or 4.
__attribute__((target("ssse3"))) void ChannelRowSsse3(const uint8_t* src, int pixels, int channels, int channel,
                                                       uint8_t* dst) {
  // Shuffle k takes from the k-th 16 source bytes the lanes of pixels 0..15 that lie there.
  alignas(16) uint8_t masks[4][16];
  for (int k = 0; k < 4; ++k) {  // all four (the fourth is unused for 3 channels)
    for (int lane = 0; lane < 16; ++lane) {
      const int at = lane * channels + channel - 16 * k;
      masks[k][lane] = at >= 0 && at < 16 ? static_cast<uint8_t>(at) : 0x80;
    }
  }
  const __m128i m0 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[0]));
  const __m128i m1 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[1]));
  const __m128i m2 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[2]));
  const __m128i m3 = _mm_load_si128(reinterpret_cast<const __m128i*>(masks[3]));
  const int bytes = 16 * channels;
  int i = 0;
  for (; i + 16 <= pixels; i += 16, src += bytes) {
    const __m128i* v = reinterpret_cast<const __m128i*>(src);
    __m128i out = _mm_or_si128(_mm_shuffle_epi8(_mm_loadu_si128(v), m0),
                               _mm_or_si128(_mm_shuffle_epi8(_mm_loadu_si128(v + 1), m1),
                                            _mm_shuffle_epi8(_mm_loadu_si128(v + 2), m2)));
    if (channels == 4) out = _mm_or_si128(out, _mm_shuffle_epi8(_mm_loadu_si128(v + 3), m3));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + i), out);
  }
  for (int k = 0; i < pixels; ++i, ++k) dst[i] = src[k * channels + channel];
}

}  // namespace rotoscan::laser::detail
#endif  // ROTOSCAN_HAVE_SSSE3_PATH
