// wos_poisson: the Walk-on-Spheres core as a scene plugin: solves Laplacian(u) = f in a 2D region bounded by the
// domain box (walls) and <boundary> shapes, u = each boundary's value on it, at the centre of every pixel of a
// resolution x resolution image, with `walks` walks per pixel (thesis Eqs. 3.74-3.79; see docs/boundaries.md).
// A boundary's value is its `stream_value` (the same parameter the fluid solver uses as its isovalue); the walls'
// value is `wall_value`. The optional source f is a nested <vorticity> field, cached on the image's grid
// (bilinear) and importance-sampled like the fluid's vorticity. The seed is --seed; --spp overrides `walks`.
//
// Output image (the CLI writes it to -o): R, G, B (u colour-mapped, blue-white-red over +-max|u|), "u",
// "u_variance" (of the pixel's estimate), "solid" (1 inside a solid), and with gradient = true "du_dx",
// "du_dy" (antithetic gradient estimator). Counters: wos.walks, wos.steps, wos.truncated, wos.invalid,
// wos.boundary_queries.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <simulation type="wos_poisson">
//         <boundary type="disk"><float name="radius" value="0.3"/><float name="stream_value" value="1"/></boundary>
//     </simulation>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>
#include <kelvin/fluid/output.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class WosPoisson final : public Job {
public:
    explicit WosPoisson(const Properties& props) {
        const Vec3d lo = props.get_point("min"), hi = props.get_point("max");
        if (!(hi.x > lo.x) || !(hi.y > lo.y) || !std::isfinite(lo.x + lo.y + hi.x + hi.y))
            props.error("max", "must exceed min in x and y (finite)");
        m_domain = {{lo.x, lo.y}, {hi.x, hi.y}, false};
        m_res = int(props.get_int("resolution", 2, 16384));
        m_walks = int(props.get_int("walks", 1, 1 << 24));
        m_options.wos.epsilon = props.get_float("epsilon", 0.0, 1e300);
        m_options.wos.max_steps = int(props.get_int("max_steps", 1, 1 << 30));
        m_options.walls = props.get_bool("walls");
        m_options.wall_stream_value = props.get_float("wall_value");
        if (!std::isfinite(m_options.wall_stream_value)) props.error("wall_value", "must be finite");
        m_gradient = props.get_bool("gradient");
        m_source = props.get_object_as<VorticityField>("source");
        for (const ObjectPtr& o : props.get_objects("boundary")) {
            auto b = std::dynamic_pointer_cast<const BoundaryShape>(o);
            if (!b || b->dimension() != 2) props.error("boundary", "wos_poisson is 2D: give 2D boundaries");
            if (b->role().moving())
                props.error("boundary", "wos_poisson solves a static problem: boundaries cannot move");
            m_options.shapes.push_back(b);
        }
        if (const std::string why = check_wos_options(m_options, m_domain); !why.empty()) props.error("walls", why);
    }

    RunResult run(RunContext& ctx) override {
        Timer timer;
        const int nx = m_res;
        const int ny = std::max(2, int(std::lround(nx * m_domain.size().y / m_domain.size().x)));
        const int walks = ctx.spp > 0 ? int(std::min<long long>(ctx.spp, 1 << 24)) : m_walks;
        Grid2 source(m_domain, nx, ny);
        if (m_source)
            for (int j = 0; j < ny; ++j)
                for (int i = 0; i < nx; ++i) {
                    const double f = m_source->vorticity(source.cell_center(i, j));
                    source.at(i, j) = std::isfinite(f) ? f : 0.0;
                }
        WosVelocityField field(m_options, m_domain, m_source ? &source : nullptr, Interpolation::Bilinear, 0);
        // The walks poll the job's token within an estimate (wos/wos.h, StopPollSamples), so a stop lands within a
        // fraction of a second even at millions of walks per pixel.
        struct Stop final : Cancellable {};
        Stop stop;
        stop.set_cancel_token(ctx.cancel);
        field.set_stop(&stop);
        log_info("wos_poisson: {}x{} pixels, {} walks each, epsilon {:g}, max_steps {}; boundaries {}; source {}", nx,
                 ny, walks, field.settings().epsilon, field.settings().max_steps, describe(m_options, m_domain),
                 m_source ? m_source->description() : std::string("none (Laplace)"));
        Bitmap img(nx, ny, {"R", "G", "B", "u", "u_variance", "solid"});
        if (m_gradient) {
            img.add_channel("du_dx");
            img.add_channel("du_dy");
        }
        std::vector<wos::WalkCounters> rows(static_cast<std::size_t>(ny), wos::WalkCounters{});
        ProgressReporter progress(ctx, "Solving", double(ny), "rows");
        parallel_for_units(std::size_t(ny), [&](std::size_t row) {
            if (ctx.cancel.stop_requested()) return;  // rows not solved stay zero; the result says interrupted
            const int j = int(row);
            Random rng(ctx.seed, row);
            for (int i = 0; i < nx; ++i) {
                if (ctx.cancel.stop_requested()) return;  // an estimate cut short is not written
                const Vec2d x = source.cell_center(i, j);
                const int y = ny - 1 - j;  // top row = largest y
                if (field.solid_at(x) >= 0) {
                    img.at(i, y, 5) = 1;
                    continue;
                }
                const wos::ScalarEstimate u = field.stream_function(x, walks, rng, rows[row]);
                if (ctx.cancel.stop_requested()) return;
                img.at(i, y, 3) = float(u.value);
                img.at(i, y, 4) = float(u.variance);
                if (m_gradient) {  // v = (-du/dy, du/dx)
                    const VelocityEstimate v = field.estimate(x, walks, rng, rows[row]);
                    if (ctx.cancel.stop_requested()) return;
                    img.at(i, y, 6) = float(v.value.y);
                    img.at(i, y, 7) = float(-v.value.x);
                }
            }
            progress.update(1);
        });
        progress.finish();
        float range = 0;
        for (int y = 0; y < ny; ++y)
            for (int i = 0; i < nx; ++i) range = std::max(range, std::abs(img.at(i, y, 3)));
        for (int y = 0; y < ny; ++y)
            for (int i = 0; i < nx; ++i)
                img.set_rgb(
                    i, y,
                    img.at(i, y, 5) > 0 ? Color3(0.2) : diverging_colormap(range > 0 ? img.at(i, y, 3) / range : 0));
        wos::WalkCounters c;
        for (const auto& r : rows) c += r;
        report_walks(ctx.stats, "wos.", c, "wos_poisson", m_options.wos.max_steps);
        RunResult result;
        result.interrupted = ctx.cancel.stop_requested();
        result.image = std::move(img);
        result.work = double(walks);
        result.work_unit = "walks/pixel";
        result.seconds = timer.seconds();
        return result;
    }

private:
    Domain2 m_domain;
    int m_res = 128, m_walks = 256;
    bool m_gradient = false;
    WosVelocityOptions m_options;
    std::shared_ptr<VorticityField> m_source;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::WosPoisson, "simulation", "wos_poisson",
              "Walk-on-Spheres Poisson/Laplace solver on an image (Laplacian u = f, u = boundary values).",
              kelvin::param::point("min", kelvin::Vec3d(-1.0, -1.0, 0.0), "image box corner (z = 0)"),
              kelvin::param::point("max", kelvin::Vec3d(1.0, 1.0, 0.0), "image box corner (z = 0)"),
              kelvin::param::integer("resolution", 128, "pixels along x"),
              kelvin::param::integer("walks", 256, "walks per pixel (--spp overrides)"),
              kelvin::param::real("epsilon", 0.0, "shell width; 0: 1e-4 x the box's smaller side"),
              kelvin::param::integer("max_steps", 4096, "spheres per walk before truncation (counted)"),
              kelvin::param::boolean("walls", true, "the box is a boundary with value wall_value"),
              kelvin::param::real("wall_value", 0.0, "u on the walls"),
              kelvin::param::boolean("gradient", false, "also estimate grad u (du_dx, du_dy channels)"),
              kelvin::param::object("source", "vorticity", "source term f (a <vorticity> field); none: Laplace"),
              kelvin::param::objects("boundary", "boundaries; u = their stream_value"));
