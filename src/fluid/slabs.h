#pragma once
// Internal: the per-cell passes of the MCFluid solvers (2D rows, 3D z slabs) and the dye, spread over the ranks of a
// distributed run (issue 21, core/distributed.h).
//
// A pass is split into units (a row of a 2D grid, a z slab of a 3D one) whose random streams depend on the unit's
// index only. Rank r runs the contiguous slab of units it owns (Communicator::slab, in rank order); then
//
//  - one allreduce sums the pass's integer work counters over the ranks and tells every rank whether any rank was
//    stopped (so that all ranks leave the pass, and the step, together: none is left waiting in a collective);
//  - one allgather gives every rank the other ranks' slabs of the fields the pass wrote. The grids store a unit's
//    cells contiguously (x fastest, then y, then z), so a slab is one block of each field; every value is computed
//    by exactly one rank and copied, never summed, so every rank ends the pass with the grids of a single process,
//    bit for bit, before the next pass reads them.
//
// With one rank nothing is communicated or copied: the pass is the single-process pass.
#include <kelvin/core/distributed.h>
#include <kelvin/core/parallel.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <type_traits>
#include <vector>

namespace kelvin::fluid {

class SlabPass {
public:
    /// A pass over `units` units of `unit_cells` values per field each, on the ranks of `comm`.
    SlabPass(Communicator& comm, std::size_t units, std::size_t unit_cells);

    /// This rank's units: [begin(), end()).
    std::size_t begin() const { return m_begin; }
    std::size_t end() const { return m_end; }
    std::size_t size() const { return m_end - m_begin; }

    /// body(unit) for each of this rank's units, on this rank's threads.
    void run(const std::function<void(std::size_t unit)>& body) const {
        parallel_for_units(size(), [&](std::size_t i) { body(m_begin + i); });
    }

    /// Sums `work` over the ranks, in place (integer sums: exact, whatever the order), and returns true on every
    /// rank when `stopped` is true on any rank. One allreduce. `Work` holds uint64_t counters only (the solvers'
    /// per-unit work records and wos::WalkCounters), so it is an array of them.
    template <class Work>
    bool reduce(Work& work, bool stopped) {
        static_assert(std::is_trivially_copyable_v<Work> && sizeof(Work) % sizeof(uint64_t) == 0);
        if (!m_comm.distributed()) return stopped;
        constexpr std::size_t n = sizeof(Work) / sizeof(uint64_t);
        std::array<uint64_t, n + 1> v;
        std::memcpy(v.data(), &work, sizeof(Work));
        v[n] = stopped ? 1 : 0;
        m_comm.allreduce(v.data(), v.size(), ReduceOp::Sum);
        std::memcpy(static_cast<void*>(&work), v.data(), sizeof(Work));  // trivially copyable (asserted above)
        return v[n] != 0;
    }

    /// Copies the other ranks' slabs of each of `fields` (units x unit_cells values each) into this rank's copy, so
    /// that every rank holds the whole of every field. One allgather of this rank's slabs, field after field.
    void gather(const std::vector<std::vector<double>*>& fields);

private:
    Communicator& m_comm;
    std::size_t m_units, m_unit_cells;
    std::size_t m_begin = 0, m_end = 0;
};

}  // namespace kelvin::fluid
