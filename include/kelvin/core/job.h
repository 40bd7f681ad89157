#pragma once
// A Job is what `kelvin scene.xml` runs: a render (the scene's integrator) or a simulation. The CLI and host
// applications drive it through RunContext and read back a RunResult (docs/host-api.md).
#include <kelvin/core/checkpoint.h>
#include <kelvin/core/image.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/object.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/stats.h>

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>

namespace kelvin {

class Communicator;

/// A pixel window of the film, [x0, x1) x [y0, y1) in pixels of the full image (`kelvin --crop`). Empty (the
/// default): the whole film.
struct CropWindow {
    int x0 = 0, x1 = 0, y0 = 0, y1 = 0;
    bool empty() const { return x1 <= x0 || y1 <= y0; }
    int width() const { return x1 - x0; }
    int height() const { return y1 - y0; }
};

struct RunContext {
    uint64_t seed = 0;
    long long spp = -1;        ///< override of the sample count (-1: the scene's own)
    double time_limit = 0;     ///< seconds; 0 = none (equal-time runs stop after this)
    double write_partial = 0;  ///< seconds between partial outputs; 0 = never
    bool quiet = false;        ///< no progress line on stderr (on_progress still gets every report)
    /// Label of the main progress line ("Rendering" when empty); nested passes (an MLT direct pass) set their own.
    std::string progress_label;
    /// Structured progress for a host (core/progress.h): every pass of the job (sample passes, an MLT
    /// bootstrap and direct-light pass, simulation steps) reports its start, then at most every 0.1 s, then a
    /// final report. Called from the job's threads, one call at a time; keep it short and do not throw.
    ProgressCallback on_progress;
    /// Set by a job running another job as one of its passes (MLT's direct-light render): that job's reports
    /// are flagged ProgressInfo::nested.
    bool progress_nested = false;
    /// This job's cancellation token. Keep a copy and call cancel() from any thread: the job stops at its next
    /// poll (within a pass, a row of pixels or cells) and returns what it has with RunResult::interrupted set.
    /// Only this job stops; a process-wide interrupt (Ctrl-C in `kelvin`, request_interrupt()) stops every job.
    CancelToken cancel;
    /// Render only this window of the film (renders by sampling integrators; others refuse a non-empty one).
    CropWindow crop;
    std::filesystem::path output;  ///< main output file (renders) or output prefix (simulations)
    /// Called with the image so far every `write_partial` seconds. (On interruption the job returns early
    /// with RunResult::interrupted set and the image so far; the caller writes it.)
    std::function<void(const Bitmap&)> write_partial_image;
    Stats stats;
    /// The ranks this job is spread over (core/distributed.h); null: this process alone. With several ranks every
    /// rank calls run() with the same settings; the result (image, fields, statistics) is complete on rank 0, and
    /// only rank 0 reports progress and calls write_partial_image. `kelvin` under mpirun sets the world here.
    Communicator* comm = nullptr;

    // ----- checkpoints (convergence studies, `kelvin converge`): intermediate results without restarting.
    // Contract for every job (see core/checkpoint.h; run_passes and mcfluid implement it): when
    // `on_checkpoint` is set, the job calls it once per scheduled checkpoint, at the first moment its work
    // reaches it, with the elapsed compute time (excluding time spent in the callback), the work done and an
    // accessor to the result so far (an image; simulations also the fields on their grid). Work checkpoints
    // are hit exactly (a render at checkpoint_work = {4} reports the same image as a 4 spp render with the
    // same seed); time checkpoints fire at the end of the pass or step that crosses them. The time limit
    // and a work target end the run after the checkpoints due at that moment have fired. Checkpoints are
    // never reported after an interruption.
    std::vector<double> checkpoint_seconds;    ///< compute times (seconds), any order
    std::vector<long long> checkpoint_work;    ///< work counts: spp (renders), steps (simulations)
    std::vector<double> checkpoint_sim_times;  ///< simulated times (simulations only)
    CheckpointCallback on_checkpoint;
};

struct RunResult {
    Bitmap image;              ///< final image (renders); may be empty for simulations
    bool interrupted = false;  ///< stopped early (ctx.cancel or a signal); `image` holds what was computed
    double seconds = 0;
    double work = 0;          ///< samples, paths or steps done
    std::string work_unit;    ///< "spp", "steps", ...
    std::string description;  ///< what ran, with its variant ("drmlt (orbital, Tierney–Mira)"); set by the job
    std::vector<std::filesystem::path> files_written;  ///< outputs the job wrote itself
};

class Job : public Object {
public:
    virtual RunResult run(RunContext& ctx) = 0;
    /// True if run() spreads its work over the ranks of RunContext::comm (core/distributed.h) with a result
    /// identical to one process's. A scene whose job is not (the grid and particle baselines) runs on rank 0
    /// alone; the other ranks return at once.
    virtual bool distributable() const { return false; }
    /// The job this one runs on its behalf, if any: a scene's <simulation> (null for a render, and for every other
    /// job). Lets a layer find a simulation in a loaded scene without knowing the scene's type.
    virtual std::shared_ptr<Job> delegate() const { return nullptr; }
};

}  // namespace kelvin
