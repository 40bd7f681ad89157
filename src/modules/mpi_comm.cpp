// Kelvin's MPI module (libkelvin_mpi.so): the world communicator over MPI (core/distributed.h). Loaded by
// world_communicator() only in processes started by an MPI launcher, so that no other run loads MPI.
//
// Collectives are called from one thread (the job's), so MPI_THREAD_FUNNELED is enough. Byte counts above 2^31 - 1
// per rank are refused with a clear error rather than truncated (MPI-3 counts are int).
#include "core/distributed_module.h"

#include <kelvin/core/error.h>

#include <mpi.h>

#include <climits>
#include <numeric>

namespace kelvin {
namespace {

MPI_Op mpi_op(ReduceOp op) {
    switch (op) {
        case ReduceOp::Max:
            return MPI_MAX;
        case ReduceOp::Min:
            return MPI_MIN;
        default:
            return MPI_SUM;
    }
}

void check(int rc, const char* what) {
    if (rc == MPI_SUCCESS) return;
    char text[MPI_MAX_ERROR_STRING];
    int len = 0;
    MPI_Error_string(rc, text, &len);
    throw RuntimeError(fmt::format("MPI: {} failed: {}", what, std::string(text, std::size_t(len))));
}

int count_of(std::size_t bytes) {
    if (bytes > std::size_t(INT_MAX))
        throw RuntimeError(fmt::format("MPI: {} bytes in one message exceed MPI's int counts", bytes));
    return int(bytes);
}

class MpiCommunicator final : public Communicator {
public:
    MpiCommunicator() {
        MPI_Comm_rank(MPI_COMM_WORLD, &m_rank);
        MPI_Comm_size(MPI_COMM_WORLD, &m_size);
    }
    int rank() const override { return m_rank; }
    int size() const override { return m_size; }
    void allreduce(double* data, std::size_t n, ReduceOp op) override { reduce(data, n, MPI_DOUBLE, op); }
    void allreduce(int64_t* data, std::size_t n, ReduceOp op) override { reduce(data, n, MPI_INT64_T, op); }
    void allreduce(uint64_t* data, std::size_t n, ReduceOp op) override { reduce(data, n, MPI_UINT64_T, op); }
    void broadcast(void* data, std::size_t bytes) override {
        count(m_rank == 0 ? bytes : 0);
        check(MPI_Bcast(data, count_of(bytes), MPI_BYTE, 0, MPI_COMM_WORLD), "MPI_Bcast");
    }
    std::vector<char> allgather(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets) override {
        return collect(data, bytes, offsets, /*all=*/true);
    }
    std::vector<char> gather(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets) override {
        return collect(data, bytes, offsets, /*all=*/false);
    }
    void barrier() override {
        count(0);
        check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier");
    }
    Traffic traffic() const override { return m_traffic; }
    [[noreturn]] void abort(int exit_code) override {
        MPI_Abort(MPI_COMM_WORLD, exit_code);
        std::_Exit(exit_code);
    }

private:
    void reduce(void* data, std::size_t n, MPI_Datatype type, ReduceOp op) {
        // In chunks of at most 2^28 elements (int counts).
        constexpr std::size_t Chunk = std::size_t(1) << 28;
        int bytes_per = 0;
        MPI_Type_size(type, &bytes_per);
        count(n * std::size_t(bytes_per));
        for (std::size_t i = 0; i < n; i += Chunk) {
            const int c = int(std::min(Chunk, n - i));
            check(MPI_Allreduce(MPI_IN_PLACE, static_cast<char*>(data) + i * std::size_t(bytes_per), c, type,
                                mpi_op(op), MPI_COMM_WORLD),
                  "MPI_Allreduce");
        }
    }
    std::vector<char> collect(const void* data, std::size_t bytes, std::vector<std::size_t>* offsets, bool all) {
        const int mine = count_of(bytes);
        count(bytes);
        std::vector<int> counts(std::size_t(m_size), 0), displs(std::size_t(m_size), 0);
        if (all)
            check(MPI_Allgather(&mine, 1, MPI_INT, counts.data(), 1, MPI_INT, MPI_COMM_WORLD), "MPI_Allgather");
        else
            check(MPI_Gather(&mine, 1, MPI_INT, counts.data(), 1, MPI_INT, 0, MPI_COMM_WORLD), "MPI_Gather");
        std::size_t total = 0;
        for (int r = 0; r < m_size; ++r) {
            displs[std::size_t(r)] = int(total);
            total += std::size_t(counts[std::size_t(r)]);
        }
        const bool receives = all || m_rank == 0;
        if (receives) count_of(total);
        std::vector<char> out(receives ? total : 0);
        if (offsets) {
            offsets->assign(std::size_t(m_size) + 1, 0);
            if (receives)
                for (int r = 0; r < m_size; ++r)
                    (*offsets)[std::size_t(r) + 1] = (*offsets)[std::size_t(r)] + std::size_t(counts[std::size_t(r)]);
        }
        // MPI wants a non-null send buffer even for zero bytes on some implementations.
        static char empty = 0;
        const void* send = bytes ? data : &empty;
        if (all)
            check(MPI_Allgatherv(send, mine, MPI_BYTE, out.data(), counts.data(), displs.data(), MPI_BYTE,
                                 MPI_COMM_WORLD),
                  "MPI_Allgatherv");
        else
            check(MPI_Gatherv(send, mine, MPI_BYTE, out.data(), counts.data(), displs.data(), MPI_BYTE, 0,
                              MPI_COMM_WORLD),
                  "MPI_Gatherv");
        return out;
    }

    void count(std::size_t bytes) {
        ++m_traffic.collectives;
        m_traffic.bytes += bytes;
    }

    int m_rank = 0, m_size = 1;
    Traffic m_traffic;
};

MpiCommunicator* the_world = nullptr;

Communicator* init(std::string* error) {
    int initialised = 0;
    MPI_Initialized(&initialised);
    if (!initialised) {
        int provided = 0;
        if (MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) {
            *error = "MPI_Init_thread failed";
            return nullptr;
        }
        if (provided < MPI_THREAD_FUNNELED) {
            *error = "the MPI library does not provide MPI_THREAD_FUNNELED";
            return nullptr;
        }
    }
    // Errors come back as codes (and become exceptions), instead of aborting the job from inside MPI.
    MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
    if (!the_world) the_world = new MpiCommunicator();  // lives for the process
    return the_world;
}

void finalize() {
    int initialised = 0, finalised = 0;
    MPI_Initialized(&initialised);
    MPI_Finalized(&finalised);
    if (initialised && !finalised) MPI_Finalize();
}

const detail::MpiModule table{&init, &finalize};

}  // namespace
}  // namespace kelvin

extern "C" __attribute__((visibility("default"))) const void* kelvin_mpi_module_v1() { return &kelvin::table; }
