// A host driving a fluid simulation loaded from XML itself: take the scene's solver, step it, and ask for the
// vorticity and velocity at points of its choosing; compare with the exact solution where the scene has one
// (the Lamb–Oseen vortex of scenes/fluid/lamb_oseen.xml in 2D, the steady ABC flow of scenes/fluid/abc.xml in
// 3D).
//   fluid_pointwise scene.xml [steps] [-D name=value]...
#include <kelvin/core/error.h>
#include <kelvin/core/parser.h>
#include <kelvin/fluid/simulation.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace {

// 3D: the solver's grids and pointwise queries (MCFluid3Solver), the vorticity compared with the exact solution.
int drive_3d(const kelvin::fluid::Simulation& sim, long long steps) {
    const kelvin::fluid::TimeStepping ts = sim.time_stepping();
    kelvin::RunContext ctx;
    ctx.seed = 1;
    std::unique_ptr<kelvin::fluid::MCFluid3Solver> solver = sim.create_solver3(ctx);
    for (long long s = 1; s <= steps; ++s)
        if (!solver->step(ts.step_length(s, solver->time()))) break;
    const double t = solver->time();
    std::printf("t = %g after %lld steps (3D)\n", t, solver->step_index());
    std::printf("%8s %8s %8s  %12s %12s  %12s\n", "x", "y", "z", "|omega|", "|omega| exact", "|u|");
    const kelvin::fluid::VorticityField3* field = sim.vorticity_field3();
    const kelvin::fluid::VectorGrid3& grid = solver->vorticity_grid();
    const int n = grid.x.nx();
    double worst = 0, peak = 0;
    for (int k = 0; k < 6; ++k) {
        const int i = (n / 2 + k * n / 12) % n, j = (n / 3 + k * n / 16) % n, l = (n / 4 + k * n / 20) % n;
        const kelvin::Vec3d x = grid.x.cell_center(i, j, l);
        const kelvin::Vec3d w = solver->vorticity_at(x), u = solver->velocity_at(x);
        const auto we = field ? field->exact_vorticity3(t, x, sim.viscosity()) : std::optional<kelvin::Vec3d>();
        std::printf("%8.3f %8.3f %8.3f  %12.5g %12.5g  %12.5g\n", x.x, x.y, x.z, glm::length(w),
                    we ? glm::length(*we) : NAN, glm::length(u));
        if (std::abs(w.x - grid.x.at(i, j, l)) > 1e-9 * (1 + std::abs(w.x))) {
            std::fprintf(stderr, "vorticity_at disagrees with the solver's grid at a cell centre\n");
            return 1;
        }
        if (we) {
            worst = std::max(worst, glm::length(w - *we));
            peak = std::max(peak, glm::length(*we));
        }
    }
    if (peak > 0) std::printf("largest vorticity error %.3g (%.2g%% of the peak)\n", worst, 100 * worst / peak);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s scene.xml [steps] [-D name=value]...\n", argv[0]);
        return 2;
    }
    long long steps = -1;
    kelvin::ParseOptions popts;
    for (int i = 2; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "-D" && i + 1 < argc) {
            const std::string d = argv[++i];
            const auto eq = d.find('=');
            if (eq == std::string::npos) {
                std::fprintf(stderr, "-D %s: expected NAME=VALUE\n", d.c_str());
                return 2;
            }
            popts.defines[d.substr(0, eq)] = d.substr(eq + 1);
        } else {
            steps = std::atoll(a.c_str());
        }
    }
    try {
        kelvin::ObjectPtr scene = kelvin::load_scene(argv[1], popts);
        std::shared_ptr<kelvin::fluid::Simulation> sim = kelvin::fluid::find_simulation(scene);
        const kelvin::fluid::TimeStepping ts = sim->time_stepping();
        if (steps < 0) steps = ts.steps;
        if (sim->dimension() == 3) return drive_3d(*sim, steps);

        kelvin::RunContext ctx;  // the seed, --spp (n_mc) and the cancel token the solver uses
        ctx.seed = 1;
        std::unique_ptr<kelvin::fluid::FluidSolver> solver = sim->create_solver(ctx);
        // Steps as run() takes them (the last one shortened to land on the scene's end time).
        for (long long s = 1; s <= steps; ++s)
            if (!solver->step(ts.step_length(s, solver->time()))) break;  // false: ctx.cancel or an interrupt

        const double t = solver->time();
        std::printf("t = %g after %lld steps\n", t, solver->step_index());
        std::printf("%8s %8s  %12s %12s  %12s %12s %12s\n", "x", "y", "omega", "omega exact", "|u|", "|u| exact",
                    "grid omega");
        const kelvin::fluid::VorticityField* field = sim->vorticity_field().get();
        const kelvin::fluid::Grid2& grid = solver->vorticity_grid();
        double worst = 0, peak = 0;
        for (int k = 0; k < 6; ++k) {
            // Cell centres along the diagonal, so the grid's own value is there to compare with.
            const int i = grid.nx() / 2 + k * grid.nx() / 16, j = grid.ny() / 2 + k * grid.ny() / 32;
            const kelvin::Vec2d x = grid.cell_center(i, j);
            const double w = solver->vorticity_at(x);
            const kelvin::Vec2d u = solver->velocity_at(x);
            const auto we = field->exact_vorticity(t, x, sim->viscosity());
            const auto ue = field->exact_velocity(t, x, sim->viscosity());
            std::printf("%8.3f %8.3f  %12.5g %12.5g  %12.5g %12.5g %12.5g\n", x.x, x.y, w, we ? *we : NAN,
                        std::hypot(u.x, u.y), ue ? std::hypot(ue->x, ue->y) : NAN, grid.at(i, j));
            if (std::abs(w - grid.at(i, j)) > 1e-9 * (1 + std::abs(w))) {
                std::fprintf(stderr, "vorticity_at disagrees with the solver's grid at a cell centre\n");
                return 1;
            }
            if (we) {
                worst = std::max(worst, std::abs(w - *we));
                peak = std::max(peak, std::abs(*we));
            }
        }
        if (peak > 0) std::printf("largest vorticity error %.3g (%.2g%% of the peak)\n", worst, 100 * worst / peak);
    } catch (const kelvin::InputError& e) {
        std::fprintf(stderr, "bad scene: %s\n", e.what());
        return 2;
    } catch (const kelvin::Error& e) {
        std::fprintf(stderr, "kelvin: %s\n", e.what());
        return 1;
    }
    return 0;
}
