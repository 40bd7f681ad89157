#pragma once
// Random numbers: PCG32 (O'Neill 2014) from pcg-cpp (Debian's libpcg-cpp-dev), wrapped so that the
// rest of Kelvin names one type. Determinism rule: work is split into units whose count does not depend on
// the number of threads; unit u of a run with seed s draws from Random(s, u), a PCG32 stream of its own.
#include <kelvin/core/math.h>

#include <pcg_random.hpp>

#include <cmath>
#include <cstdint>

namespace kelvin {

/// Mix two integers into one well-distributed 64-bit value (SplitMix64 finaliser); used to derive stream
/// indices such as (pass, tile) -> stream.
constexpr uint64_t hash_combine(uint64_t a, uint64_t b) {
    uint64_t z = a ^ (b + 0x9e3779b97f4a7c15ULL + (a << 6) + (a >> 2));
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

class Random;

/// Two independent standard normal variates (Box–Muller).
inline Vec2d standard_normal2(Random& rng);

class Random {
public:
    /// Stream `stream` of the generator seeded with `seed`. Distinct streams are statistically independent.
    explicit Random(uint64_t seed = 0, uint64_t stream = 0) : m_rng(hash_combine(seed, 0x6b656c76696eULL), stream) {}
    void seed_stream(uint64_t seed, uint64_t stream) { m_rng.seed(hash_combine(seed, 0x6b656c76696eULL), stream); }

    uint32_t next_u32() { return m_rng(); }
    /// The next `n` values of next_u32, bit for bit, in order: eight interleaved LCG chains in vector lanes
    /// (state k + 8 is a^8 state k + c (1 + a + ... + a^7)) instead of one serial chain, so hot loops that need
    /// many draws are bound neither by the multiply latency of the generator nor by its scalar output function.
    void fill_u32(uint32_t* out, int n) { m_rng.fill(out, n); }
    /// Uniform in [0, bound) without modulo bias.
    uint32_t next_u32(uint32_t bound) { return m_rng(bound); }
    /// Uniform in [0, 1) with 24 random bits (never returns 1).
    float next_float() { return float(m_rng() >> 8) * 0x1p-24f; }
    /// Uniform in [0, 1) with 53 random bits (never returns 1).
    double next_double() {
        uint64_t hi = m_rng(), lo = m_rng();
        return double(((hi << 32) | lo) >> 11) * 0x1p-53;
    }
    Vec2d next_2d() {
        double a = next_double();
        return {a, next_double()};
    }
    /// Jump ahead by `delta` draws of next_u32 in O(log delta).
    void advance(uint64_t delta) { m_rng.advance(delta); }
    /// Go back by `delta` draws.
    void backstep(uint64_t delta) { m_rng.backstep(delta); }

    bool operator==(const Random& o) const { return m_rng == o.m_rng; }

private:
    /// n successive PCG32 (XSH RR, 64-bit state) outputs from `state` with multiplier a and increment c, in vector
    /// lanes (src/core/random.cpp); returns the state after them.
    static uint64_t fill_lanes(uint64_t state, uint64_t a, uint64_t c, uint32_t* out, int n);
    /// pcg32 with access to its state for fill_u32.
    struct Engine : pcg32 {
        using pcg32::pcg32;
        void fill(uint32_t* out, int n) { state_ = fill_lanes(state_, multiplier(), increment(), out, n); }
    };
    Engine m_rng;
};

inline Vec2d standard_normal2(Random& rng) {
    const double u1 = rng.next_double(), u2 = rng.next_double();
    const double r = std::sqrt(-2.0 * std::log1p(-u1));  // u1 < 1, so the logarithm is finite
    const double a = 2 * Pi * u2;
    return {r * std::cos(a), r * std::sin(a)};
}

}  // namespace kelvin
