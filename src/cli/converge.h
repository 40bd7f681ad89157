#pragma once
// `kelvin converge`: the command-line front end of kelvin::run_convergence (core/converge.h).
#include <CLI/CLI.hpp>

#include <string>
#include <vector>

namespace kelvin {
class Communicator;
}

namespace kelvin::cli {

struct ConvergeArgs {
    std::string scene, reference, output, config_file, images = "first";
    std::vector<std::string> configs, sweeps, defines, fields, plugin_paths;
    std::string seconds, spp, steps, times, pixels, window, disk;
    std::string plot_metrics, plot_formats = "png";  ///< --plot-metrics, --plot-formats (plot_convergence.py)
    std::string plot_list;  ///< --plot=LIST: metrics and formats in one list (formats are png, svg, pdf)
    const CLI::Option* plot_option = nullptr;          ///< --plot (given with or without a list)
    const CLI::Option* plot_formats_option = nullptr;  ///< --plot-formats
    int runs = 1, threads = 0;
    std::string seed = "0";
    double epsilon = 1e-2;
    bool plot = false, allow_unused = false, quiet = false, verbose = false;
};

/// Adds the `converge` sub-command to `app`, filling `args`.
CLI::App* add_converge_command(CLI::App& app, ConvergeArgs& args);
/// Runs it: exit code 0, 1 (runtime failure, e.g. the plot script failed), 130 (interrupted); throws
/// InputError on bad input (the caller prints it and exits with 2).
/// `world`: the ranks of an MPI job (core/distributed.h); the study's runs are spread over them.
int run_converge(const ConvergeArgs& args, Communicator& world);

}  // namespace kelvin::cli
