// The batched PCG32 draw behind Random::fill_u32 (random.h): eight interleaved LCG chains in vector lanes, for the
// hot loops that need many draws at once (the 3D Biot–Savart sampler). Bit for bit the serial sequence.
#include <kelvin/core/random.h>

#include <cstring>

namespace kelvin {

namespace {
typedef uint64_t U64x4 __attribute__((vector_size(32)));
typedef uint32_t U32x8 __attribute__((vector_size(32)));

inline uint32_t xsh_rr(uint64_t s) {
    const uint32_t x = uint32_t(((s >> 18u) ^ s) >> 27u), rot = uint32_t(s >> 59u);
    return (x >> rot) | (x << ((-rot) & 31u));
}
}  // namespace

// Lanes l = 0..7 hold the states of draws i + l; one step of every lane is state * a^8 + c (1 + a + ... + a^7). The
// AVX2 clone does the 64-bit products with vpmuludq and the rotations with vpsrlvq; the baseline clone is
// the same arithmetic, emulated. Integer arithmetic: both give the serial values exactly.
__attribute__((target_clones("avx2", "default"))) uint64_t Random::fill_lanes(uint64_t state, uint64_t a, uint64_t c,
                                                                              uint32_t* out, int n) {
    int i = 0;
    if (n >= 8) {
        uint64_t lane[8], ak = 1, ck = 0;  // after the loop: ak = a^8, ck = c (1 + a + ... + a^7)
        for (int l = 0; l < 8; ++l) {
            lane[l] = state * ak + ck;
            ck = ck * a + c;
            ak *= a;
        }
        U64x4 lo = {lane[0], lane[1], lane[2], lane[3]}, hi = {lane[4], lane[5], lane[6], lane[7]};
        for (; i + 8 <= n; i += 8) {
            // PCG32's XSH RR output (pcg-cpp's xsh_rr_mixin, 64-bit state, 32-bit output) in the low halves of the
            // 64-bit lanes: the 32-bit value doubled into both halves, so that one variable 64-bit shift rotates it.
            const U64x4 xl = ((lo >> 18u) ^ lo) >> 27u, xh = ((hi >> 18u) ^ hi) >> 27u;
            const U64x4 rl = ((xl & 0xffffffffu) | (xl << 32u)) >> (lo >> 59u);
            const U64x4 rh = ((xh & 0xffffffffu) | (xh << 32u)) >> (hi >> 59u);
            const U32x8 o = __builtin_shufflevector(U32x8(rl), U32x8(rh), 0, 2, 4, 6, 8, 10, 12, 14);
            std::memcpy(out + i, &o, sizeof o);
            lo = lo * ak + ck;
            hi = hi * ak + ck;
        }
        state = lo[0];
    }
    for (; i < n; ++i) {
        out[i] = xsh_rr(state);
        state = state * a + c;
    }
    return state;
}

}  // namespace kelvin
