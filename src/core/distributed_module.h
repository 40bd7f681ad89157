#pragma once
// The table of Kelvin's MPI module (libkelvin_mpi.so, src/modules/mpi_comm.cpp), loaded by world_communicator().
#include <kelvin/core/distributed.h>

#include <string>

#define KELVIN_MPI_MODULE_ENTRY "kelvin_mpi_module_v1"

namespace kelvin::detail {

struct MpiModule {
    /// MPI_Init_thread (MPI_THREAD_FUNNELED) and the world communicator, or null with `error` set.
    Communicator* (*init)(std::string* error);
    /// MPI_Finalize, if init succeeded and MPI is not finalised yet.
    void (*finalize)();
};

}  // namespace kelvin::detail
