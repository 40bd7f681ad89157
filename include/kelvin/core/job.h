#pragma once
// A Job is what `kelvin scene.xml` runs: a render (the scene's integrator) or a simulation. The CLI and host
// applications drive it through RunContext and read back a RunResult.
#include <kelvin/core/image.h>
#include <kelvin/core/object.h>
#include <kelvin/core/stats.h>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

namespace kelvin {

struct RunContext {
    uint64_t seed = 0;
    long long spp = -1;          ///< override of the sample count (-1: the scene's own)
    double time_limit = 0;       ///< seconds; 0 = none (equal-time runs stop after this)
    double write_partial = 0;    ///< seconds between partial outputs; 0 = never
    bool quiet = false;
    std::filesystem::path output;  ///< main output file (renders) or output prefix (simulations)
    /// Called with the image so far every `write_partial` seconds. (On interruption the job returns early
    /// with RunResult::interrupted set and the image so far; the caller writes it.)
    std::function<void(const Bitmap&)> write_partial_image;
    Stats stats;
};

struct RunResult {
    Bitmap image;             ///< final image (renders); may be empty for simulations
    bool interrupted = false; ///< stopped early by a signal; `image` holds what was computed
    double seconds = 0;
    double work = 0;          ///< samples, paths or steps done
    std::string work_unit;    ///< "spp", "steps", ...
    std::vector<std::filesystem::path> files_written;  ///< outputs the job wrote itself
};

class Job : public Object {
public:
    virtual RunResult run(RunContext& ctx) = 0;
};

}  // namespace kelvin
