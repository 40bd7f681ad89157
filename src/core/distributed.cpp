// Distributed runs (core/distributed.h): the local communicator, launcher detection and the MPI module's loader.
#include "distributed_module.h"
#include "modules.h"

#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>

#include <cstdlib>
#include <mutex>
#include <stdexcept>
#include <string>

namespace kelvin {

Communicator::~Communicator() = default;

namespace {

class LocalCommunicator final : public Communicator {
public:
    int rank() const override { return 0; }
    int size() const override { return 1; }
    void allreduce(double*, std::size_t, ReduceOp) override {}
    void allreduce(int64_t*, std::size_t, ReduceOp) override {}
    void allreduce(uint64_t*, std::size_t, ReduceOp) override {}
    void broadcast(void*, std::size_t) override {}
    std::vector<char> allgather(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets) override {
        if (offsets) *offsets = {0, bytes};
        const char* p = static_cast<const char*>(data);
        return bytes ? std::vector<char>(p, p + bytes) : std::vector<char>();
    }
    std::vector<char> gather(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets) override {
        return allgather(data, bytes, offsets);
    }
    void barrier() override {}
    [[noreturn]] void abort(int exit_code) override { std::_Exit(exit_code); }
};

// An integer environment variable, or -1.
int env_int(const char* name) {
    const char* v = std::getenv(name);
    if (!v || !*v) return -1;
    char* end = nullptr;
    const long n = std::strtol(v, &end, 10);
    return end && *end == '\0' && n >= 0 && n < (1L << 30) ? int(n) : -1;
}

std::mutex world_mutex;
Communicator* world = nullptr;  // MPI's, once initialised
const detail::MpiModule* world_module = nullptr;

}  // namespace

Communicator& local_communicator() {
    static LocalCommunicator local;
    return local;
}

Communicator& communicator_of(const RunContext& ctx) { return ctx.comm ? *ctx.comm : local_communicator(); }

bool launched_by_mpi(int* size) {
    // OpenMPI's mpirun, PMIx launchers, MPICH's Hydra and Slurm's PMI set these in every rank's environment.
    for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_SIZE", "PMI_SIZE", "MPI_LOCALNRANKS"}) {
        if (const int n = env_int(name); n > 0) {
            if (size) *size = n;
            return true;
        }
    }
    if (std::getenv("PMIX_RANK") || std::getenv("PMI_RANK")) {
        if (size) *size = -1;  // the launcher does not say; MPI will
        return true;
    }
    return false;
}

int launcher_rank() {
    for (const char* name : {"OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK", "SLURM_PROCID"})
        if (const int r = env_int(name); r >= 0) return r;
    return -1;
}

Communicator& world_communicator() {
    std::lock_guard lock(world_mutex);
    if (world) return *world;
    int size = 0;
    if (!launched_by_mpi(&size)) return local_communicator();
    const detail::MpiModule* module = nullptr;
    try {
        module = static_cast<const detail::MpiModule*>(
            detail::load_module_table("libkelvin_mpi.so", KELVIN_MPI_MODULE_ENTRY, "the MPI module", /*global=*/true));
    } catch (const std::runtime_error& e) {
        if (size == 1) return local_communicator();  // mpirun -np 1: one process is one process
        throw InputError({}, fmt::format("started by an MPI launcher{}, but {}; this kelvin cannot run distributed "
                                         "(rebuild with Debian's libopenmpi-dev installed, or run without mpirun)",
                                         size > 0 ? fmt::format(" with {} ranks", size) : std::string(), e.what()));
    }
    std::string error;
    Communicator* c = module->init(&error);
    if (!c) throw RuntimeError(fmt::format("MPI could not be initialised: {}", error));
    world = c;
    world_module = module;
    return *world;
}

void finalize_world() {
    std::lock_guard lock(world_mutex);
    if (world_module) world_module->finalize();
    world = nullptr;
    world_module = nullptr;
}

void run_agreeing(Communicator& comm, const std::function<void()>& body) {
    if (!comm.distributed()) return body();
    // (kind, message) of every rank: kind 0 = fine, 1 = InputError, 2 = another error.
    char kind = 0;
    std::string message;
    try {
        body();
    } catch (const InputError& e) {
        kind = 1, message = e.what();
    } catch (const std::exception& e) {
        kind = 2, message = e.what();
    }
    std::string mine = std::string(1, kind) + message;
    std::vector<std::size_t> offsets;
    const std::vector<char> all = comm.allgather(mine.data(), mine.size(), &offsets);
    for (int r = 0; r < comm.size(); ++r) {
        const char* at = all.data() + offsets[std::size_t(r)];
        if (offsets[std::size_t(r) + 1] == offsets[std::size_t(r)] || at[0] == 0) continue;
        const std::string m =
            (r == 0 ? "" : fmt::format("rank {}: ", r)) + std::string(at + 1, all.data() + offsets[std::size_t(r) + 1]);
        if (at[0] == 1) throw InputError({}, m);
        throw RuntimeError(m);
    }
}

void parallel_for_owned_units(const Communicator& comm, std::size_t count,
                              const std::function<void(std::size_t)>& body) {
    if (comm.size() == 1) return parallel_for_units(count, body);
    const auto n = std::size_t(comm.size()), r = std::size_t(comm.rank());
    const std::size_t mine = count > r ? (count - r + n - 1) / n : 0;
    parallel_for_units(mine, [&](std::size_t i) { body(r + i * n); });
}

}  // namespace kelvin
