// The target's native SIMD width for the CPU kernels' GCC/Clang vector-extension types (rasterize_cpu.cpp,
// projection_cpu.cpp): one AVX-512 register, one AVX2 one, or one SSE/NEON one. Wider-than-native vector types are
// lowered piecewise to scalar code (GCC's -Wvector-operation-performance), which made an AVX2 build of the rasterizer
// 2x slower than its scalar code.
#pragma once

#if defined(__AVX512F__)
#define ABCGS_VEC_BYTES 64
#elif defined(__AVX__)
#define ABCGS_VEC_BYTES 32
#else
#define ABCGS_VEC_BYTES 16
#endif
