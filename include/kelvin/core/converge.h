#pragma once
// Convergence studies: "what does accuracy cost in time" (docs/convergence.md). A study runs one scene
// under several configurations (sets of -D scene parameters: integrators, sample counts, cache sizes...),
// several independent runs (seeds) each, measures the error of the result at checkpoints (compute times,
// work counts or simulated times) against a reference (an image, or a simulation's exact solution), and
// writes one CSV row per checkpoint. `kelvin converge` is the command-line front end.
//
// Output directory:
//   convergence.csv         config, run, seed, trigger, target, seconds, work, unit, sim_time, metrics..., image
//   convergence_stats.csv   config, run, seed, counter, value, unit: the job's cost counters (ctx.stats)
//   convergence.settings    what the rows depend on; a resumed study must match it
//   images/<config>/run<R>_<label>.exr|.png   the result at each checkpoint (--images first: run 0 only)
//
// Resuming: rows of (config, run) pairs already in convergence.csv are kept and not recomputed; the files
// are rewritten (atomically) after every run, with rows in a canonical order (configurations in the order
// given, then runs, then checkpoints), so an interrupted study that is resumed ends with the same rows as
// an uninterrupted one (all but the `seconds` column, with work checkpoints).
#include <kelvin/core/interrupt.h>
#include <kelvin/core/metrics.h>

#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace kelvin {

class Communicator;

struct SourceLoc;

/// One configuration: a name and the -D scene parameters it sets.
struct ConvergeConfig {
    std::string name;
    std::vector<std::pair<std::string, std::string>> defines;
    /// "a=1;b=2" (the form stored in convergence.settings).
    std::string defines_string() const;
};

/// "NAME:K=V,K=V" (or "K=V,K=V", named after itself; or "NAME:" with no parameters). InputError naming
/// `what` (e.g. "--config 'x'") when malformed.
ConvergeConfig parse_config_spec(const std::string& spec, const std::string& what);
/// A configuration file: one configuration per line, "NAME: K=V K=V" (spaces or commas between
/// parameters); blank lines and '#' comments are ignored. InputError with file:line on errors.
std::vector<ConvergeConfig> read_config_file(const std::filesystem::path& path);
/// "--sweep K=V1,V2,V3": one configuration per value, named "K=V".
std::vector<ConvergeConfig> sweep_configs(const std::string& spec);
/// "1,2,4.5": finite, non-negative numbers (InputError naming `option` otherwise), sorted and de-duplicated.
std::vector<double> parse_number_list(const std::string& text, const std::string& option);

struct ConvergeOptions {
    std::filesystem::path scene;
    std::map<std::string, std::string> defines;  ///< for every configuration (a configuration's own win)
    std::vector<ConvergeConfig> configs;         ///< at least one; names unique
    int runs = 1;                                ///< independent runs per configuration
    uint64_t seed = 0;                           ///< run r uses seed + r (the same seeds for every configuration)

    // Checkpoints: exactly one kind.
    std::vector<double> seconds;    ///< compute times; the run's time limit is the last one
    std::vector<long long> spp;     ///< renders: samples per pixel; the run renders max(spp)
    std::vector<long long> steps;   ///< simulations: steps
    std::vector<double> sim_times;  ///< simulations: simulated times

    /// Renders: an image with R, G, B (required). Simulations: an image with a channel per compared field,
    /// one pixel per cell, top row = largest y (what `kelvin sim.xml -o ref.exr` writes), over the same box;
    /// at another resolution it is interpolated bilinearly at the cell centres. Empty: the simulation's exact
    /// solution.
    std::filesystem::path reference;
    std::vector<std::string> fields = {"vorticity"};  ///< simulations: fields compared
    FieldRegion region;                               ///< simulations: cells compared
    std::optional<std::array<int, 4>> window;         ///< renders: pixels [x0, x1) x [y0, y1) compared
    double epsilon = RelativeEpsilon;

    std::filesystem::path output_dir;
    enum class Images { None, First, All } images = Images::First;
    bool allow_unused = false;
    bool quiet = false;
    /// Stops the study (and the run in progress) when cancelled; a process-wide interrupt stops it too.
    CancelToken cancel;
    /// The ranks of an MPI job (core/distributed.h); null: this process alone. Every rank calls run_convergence with
    /// the same options; a run is the unit of work (rank k runs the pending runs k, k + N, ... in study order, each
    /// on its own threads), and rank 0 alone writes the CSV, after every round of N runs, in the same order as one
    /// process. Checkpoint images are written by the rank that ran them: the output directory must be on a file
    /// system every rank sees.
    Communicator* comm = nullptr;
};

struct ConvergeSummary {
    int runs_done = 0;     ///< computed by this invocation
    int runs_skipped = 0;  ///< already in the CSV
    bool interrupted = false;
    std::size_t rows = 0;  ///< rows in the CSV now
    std::filesystem::path csv, stats_csv;
};

/// Validate the options (InputError on bad input: missing scene or reference, unknown -D names, no
/// checkpoints, a settings file that does not match...), then run every (configuration, run) pair that
/// the CSV does not have yet. Stops early (summary.interrupted) on interrupt_requested(). With several ranks
/// (ConvergeOptions::comm) the summary is the whole study's on every rank.
ConvergeSummary run_convergence(const ConvergeOptions& opts);

/// CSV helpers (RFC 4180 quoting), shared with the tests.
std::string csv_escape(const std::string& field);
/// Splits one CSV record (no embedded newlines). InputError naming `where` on an unterminated quote.
std::vector<std::string> csv_split(const std::string& line, const std::string& where);

}  // namespace kelvin
