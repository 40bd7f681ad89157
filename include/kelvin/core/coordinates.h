#pragma once
// A sequence of primary-sample coordinates in [0, 1), read by index. PrimarySampleSpace (render/pss.h) reads a
// path's random numbers through it; its owner decides what a coordinate that does not exist yet is: a plain
// vector extends itself with uniform draws (the bootstrap), a Markov chain realises the coordinate of a proposal
// from the current state and the proposal kernel (mlt/chain.h). The owner also records which coordinates were
// read, which is how a chain knows what a state's path depends on.
#include <cstddef>

namespace kelvin {

class CoordinateSource {
public:
    virtual ~CoordinateSource() = default;
    /// Coordinate i, realised on first use.
    virtual double at(std::size_t i) = 0;
};

}  // namespace kelvin
