#pragma once
// How much memory a run may use, and the check that refuses a run before it allocates more than that.
//
// Every large allocation whose size follows from the input (a 3D grid from its resolution, a mesh from its file
// size, an image from its header) is estimated first and checked here, so that a run that cannot fit ends at once
// with one line naming the input and both sizes, instead of a bare std::bad_alloc, the kernel's OOM killer or
// minutes of swapping.
#include <kelvin/core/error.h>

#include <cstdint>
#include <string>
#include <string_view>

namespace kelvin {

/// The memory this process may use, in bytes: the least of the machine's physical memory, the process's
/// address-space and data-segment limits (ulimit -v, ulimit -d) and its cgroup's limit (memory.max of cgroup v2,
/// memory.limit_in_bytes of v1: containers, systemd's MemoryMax). KELVIN_MEMORY_LIMIT (bytes, or with a K, M, G or
/// T suffix) lowers it further, for tests and shared machines.
uint64_t memory_limit();

/// "1.5 GiB", "12 MiB", "512 B".
std::string format_bytes(double bytes);

/// Throws InputError(loc, "<what> needs about X, more than the Y this process may use (<the binding limit>)")
/// when `bytes` exceeds memory_limit(). `what` names the input: "a 1024^3 grid (res)", "mesh 'big.obj'".
void check_memory(double bytes, std::string_view what, const SourceLoc& loc = {});

}  // namespace kelvin
