// Per-cell passes spread over the ranks of a distributed run (see slabs.h).
#include "fluid/slabs.h"

#include <kelvin/core/error.h>

#include <fmt/format.h>

namespace kelvin::fluid {

SlabPass::SlabPass(Communicator& comm, std::size_t units, std::size_t unit_cells)
    : m_comm(comm), m_units(units), m_unit_cells(unit_cells) {
    const auto [begin, end] = comm.slab(units);
    m_begin = begin;
    m_end = end;
}

void SlabPass::gather(const std::vector<std::vector<double>*>& fields) {
    if (!m_comm.distributed()) return;
    const std::size_t cells = m_units * m_unit_cells;
    for (const std::vector<double>* f : fields)
        if (f->size() != cells)
            throw RuntimeError(fmt::format("SlabPass::gather: a field of {} values, not {}", f->size(), cells));
    // This rank's slab of each field, one after the other (the buffer lives for the pass: one per step).
    const std::size_t mine = size() * m_unit_cells;
    std::vector<double> send(fields.size() * mine);
    std::size_t at = 0;
    for (const std::vector<double>* f : fields) {
        std::memcpy(send.data() + at, f->data() + m_begin * m_unit_cells, mine * sizeof(double));
        at += mine;
    }
    std::vector<std::size_t> offsets;
    const std::vector<char> all = m_comm.allgather(send.data(), send.size() * sizeof(double), &offsets);
    for (int r = 0; r < m_comm.size(); ++r) {
        if (r == m_comm.rank()) continue;  // already in place
        const auto [begin, end] = m_comm.slab(m_units, r);
        const std::size_t n = (end - begin) * m_unit_cells;
        const std::size_t bytes = offsets[std::size_t(r) + 1] - offsets[std::size_t(r)];
        if (bytes != fields.size() * n * sizeof(double))  // every rank computes every rank's slab alike
            throw RuntimeError(fmt::format("SlabPass::gather: rank {} sent {} bytes, not {}", r, bytes,
                                           fields.size() * n * sizeof(double)));
        const char* from = all.data() + offsets[std::size_t(r)];
        for (std::vector<double>* f : fields) {
            std::memcpy(f->data() + begin * m_unit_cells, from, n * sizeof(double));
            from += n * sizeof(double);
        }
    }
}

}  // namespace kelvin::fluid
