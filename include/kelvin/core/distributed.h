#pragma once
// Distributed runs (issue 21): one Kelvin job spread over the ranks of an MPI job, bit-identical to one process.
//
// Kelvin already splits every job into work units whose results depend on the unit index only (parallel.h), and
// merges them in a fixed order. A distributed run keeps that split: rank r runs the units it owns (round-robin,
// Communicator::owns, or contiguous slabs, Communicator::slab), and the per-unit results are merged with
// collectives that keep the single-process arithmetic:
//
//  - integer sums (fixed-point splats, counters) are associative: Sum over ranks is exact;
//  - a floating-point buffer whose every element is written by exactly one rank (a tile's pixels, a slab of cells)
//    is merged by Sum, since x + 0 = x exactly; never Sum doubles that several ranks contribute to;
//  - records whose order matters (a light tracer's splats) are gathered to rank 0 and folded there in unit order.
//
// A run's control decisions (stop after this pass, write a partial image now, pass sizes under a time limit) are
// taken from rank 0's clock and broadcast, so every rank does the same passes. Only rank 0 prints and writes.
//
// MPI itself lives in a private module (libkelvin_mpi.so, see src/core/modules.h), loaded only when the process
// was started by an MPI launcher (mpirun, mpiexec, srun): a single-process `kelvin` never loads MPI, and a build
// without MPI is unchanged. Every collective is called from the thread that runs the job (MPI_THREAD_FUNNELED);
// worker threads never communicate.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <type_traits>
#include <utility>
#include <vector>

namespace kelvin {

struct RunContext;

enum class ReduceOp { Sum, Max, Min };

/// The ranks of a run. Rank 0 is the root: it prints, writes files and decides when to stop.
class Communicator {
public:
    virtual ~Communicator();
    virtual int rank() const = 0;
    virtual int size() const = 0;
    bool root() const { return rank() == 0; }
    bool distributed() const { return size() > 1; }
    /// Round-robin ownership of work unit `unit` (balances tiles and chains whose cost varies smoothly).
    bool owns(std::size_t unit) const { return size() == 1 || int(unit % std::size_t(size())) == rank(); }
    /// The contiguous slab [begin, end) of `count` items that rank `r` owns; slabs follow rank order.
    std::pair<std::size_t, std::size_t> slab(std::size_t count, int r) const {
        const auto n = std::size_t(size());
        return {count * std::size_t(r) / n, count * (std::size_t(r) + 1) / n};
    }
    std::pair<std::size_t, std::size_t> slab(std::size_t count) const { return slab(count, rank()); }

    /// Element-wise reduction over ranks, in place, result on every rank.
    virtual void allreduce(double* data, std::size_t n, ReduceOp op) = 0;
    virtual void allreduce(int64_t* data, std::size_t n, ReduceOp op) = 0;
    virtual void allreduce(uint64_t* data, std::size_t n, ReduceOp op) = 0;
    /// Rank 0's `bytes` bytes at `data`, copied to every rank.
    virtual void broadcast(void* data, std::size_t bytes) = 0;
    /// Every rank's `bytes` bytes, concatenated in rank order, on every rank (allgather) or on rank 0 only
    /// (gather; other ranks get an empty vector). `offsets` (optional) receives size() + 1 byte offsets.
    virtual std::vector<char> allgather(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets) = 0;
    virtual std::vector<char> gather(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets) = 0;
    virtual void barrier() = 0;
    /// End every rank of the run now with `exit_code` (an error on one rank that the others cannot see).
    [[noreturn]] virtual void abort(int exit_code) = 0;

    /// What this rank has communicated so far: collective calls, and bytes it contributed to them.
    struct Traffic {
        uint64_t collectives = 0, bytes = 0;
    };
    virtual Traffic traffic() const { return {}; }
};

/// The communicator of a single process (rank 0 of 1); every collective is the identity.
Communicator& local_communicator();

/// The communicator a job runs on: ctx.comm, or the local one.
Communicator& communicator_of(const RunContext& ctx);

/// True if this process was started by an MPI launcher (OpenMPI's mpirun, MPICH's mpiexec/Hydra, PMIx, Slurm's
/// srun with PMI); `size` receives the launcher's rank count.
bool launched_by_mpi(int* size = nullptr);

/// This process's rank as its MPI launcher set it in the environment (before MPI is initialised), or -1 when no
/// launcher says (not started by one). Errors that happen before the world communicator exists (the MPI module
/// missing, MPI's initialisation failing) are printed by rank 0 alone, so that they stay one line.
int launcher_rank();

/// The world communicator: MPI_COMM_WORLD when the process was started by an MPI launcher (MPI is initialised on
/// the first call, through Kelvin's MPI module), the local communicator otherwise. Throws InputError when started
/// by a launcher with several ranks and this build has no MPI module (each rank would render the whole job).
Communicator& world_communicator();

/// Finalise MPI if world_communicator() initialised it; harmless otherwise. Call before a normal exit.
void finalize_world();

// ----- helpers over a communicator

/// Run body(unit) for the units of [0, count) this rank owns (Communicator::owns), on this rank's threads.
void parallel_for_owned_units(const Communicator& comm, std::size_t count,
                              const std::function<void(std::size_t unit)>& body);

/// Run `body` on every rank and agree on failure (collective, once `body` returns or throws): if it threw on any
/// rank, every rank throws the first failing rank's error (an InputError stays one, and a rank other than 0 is named
/// in the message: "rank 1: ..."); otherwise every rank returns. For work whose errors may differ between ranks (a
/// file one node cannot read) before the ranks work together: no rank is left waiting in a later collective, and
/// rank 0 alone can report the error once.
void run_agreeing(Communicator& comm, const std::function<void()>& body);

/// True on every rank if `flag` is true on any rank.
inline bool any_rank(Communicator& comm, bool flag) {
    if (!comm.distributed()) return flag;
    uint64_t v = flag ? 1 : 0;
    comm.allreduce(&v, 1, ReduceOp::Max);
    return v != 0;
}

/// Element-wise sum of an integer vector over ranks, in place.
template <class T>
void allreduce_sum(Communicator& comm, std::vector<T>& v) {
    static_assert(std::is_same_v<T, int64_t> || std::is_same_v<T, uint64_t> || std::is_same_v<T, double>);
    if (comm.distributed() && !v.empty()) comm.allreduce(v.data(), v.size(), ReduceOp::Sum);
}

/// The `T`s every rank contributes, concatenated in rank order, on every rank. `T` is trivially copyable.
template <class T>
std::vector<T> allgather_vector(Communicator& comm, const std::vector<T>& mine) {
    static_assert(std::is_trivially_copyable_v<T>);
    if (!comm.distributed()) return mine;
    const std::vector<char> bytes = comm.allgather(mine.data(), mine.size() * sizeof(T), nullptr);
    std::vector<T> out(bytes.size() / sizeof(T));
    if (!out.empty()) std::memcpy(out.data(), bytes.data(), out.size() * sizeof(T));
    return out;
}

}  // namespace kelvin
