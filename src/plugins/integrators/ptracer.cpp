// ptracer: light tracing (particle tracing). Paths start on emitters and every vertex is connected to the
// camera; contributions are splatted onto the pixel they land on (Veach 1997, Sec. 10.2, the t = 1 strategies
// of bidirectional path tracing). It renders caustics seen directly that a path tracer finds only by chance,
// and cannot render what a pinhole camera sees through specular surfaces (those paths need t >= 2).
//
// Each "spp" is W x H light paths; the image is the splat sum divided by the number of paths traced.
// Primary samples: emitter choice (1), emission position (2) and direction (2), lens (2); then every bounce
// consumes exactly 6: BSDF component (1), direction (2), Russian roulette (1), lens (2).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="ptracer"><integer name="max_depth" value="8"/></integrator>
#include <kelvin/core/distributed.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/film.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace kelvin {
namespace {

class LightTracer final : public Integrator {
public:
    static constexpr std::size_t PathsPerUnit = 4096;

    explicit LightTracer(const Properties& props)
        : m_max_depth(int(props.get_int("max_depth", -1, 1 << 20))),
          m_rr_depth(int(props.get_int("rr_depth", 1, 1 << 20))),
          m_hide_emitters(props.get_bool("hide_emitters")) {
        if (m_max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
    }

    bool distributable() const override { return true; }

    RunResult render(const Scene& scene, RunContext& ctx) override {
        const Sensor& sensor = *scene.sensor();
        const int w = sensor.film().width(), h = sensor.film().height();
        const std::size_t paths = std::size_t(w) * std::size_t(h);
        const std::size_t units = (paths + PathsPerUnit - 1) / PathsPerUnit;
        SplatBuffer splats(w, h, units, &sensor.film().filter());
        std::vector<SampleCounters> counters(units);
        const uint64_t seed = hash_combine(ctx.seed, 0x4c49474854ULL);  // light paths: their own streams
        // Distributed: ranks trace the units they own; splats are folded on rank 0 in unit order.
        Communicator& comm = communicator_of(ctx);
        auto traced = [&] {
            uint64_t n = 0;
            for (const auto& c : counters) n += c.samples;
            if (comm.distributed()) comm.allreduce(&n, 1, ReduceOp::Sum);
            return n;
        };
        auto develop = [&] {
            const uint64_t n = traced();
            return splats.develop(n > 0 ? 1.0 / double(n) : 0.0);
        };

        auto pass = [&](long long first, long long n, std::size_t begin, std::size_t end) {
            parallel_for_owned_units(comm, begin, end, [&](std::size_t unit) {
                std::unique_ptr<Sampler> sampler = sensor.sampler().clone();
                const std::size_t p0 = unit * PathsPerUnit, p1 = std::min(paths, p0 + PathsPerUnit);
                for (long long k = first; k < first + n; ++k)
                    for (std::size_t p = p0; p < p1; ++p) {
                        if ((p & 255) == 0 && ctx.cancel.stop_requested()) return;
                        sampler->start({int(p % std::size_t(w)), int(p / std::size_t(w))}, uint64_t(k), seed);
                        trace(scene, sensor, *sampler, splats, unit, counters[unit]);
                        ++counters[unit].samples;
                    }
            });
            splats.merge(comm);  // slices come in unit order: the fold order is the pass's
        };
        PassLoopResult loop = run_passes(ctx, sensor.sampler().sample_count(), "spp", units, pass, develop);

        RunResult result;
        result.work_unit = "spp";
        result.interrupted = loop.interrupted;
        result.image = develop();
        result.seconds = loop.seconds;
        result.work = double(loop.done);
        ctx.stats.set("render.spp", double(loop.done), "spp");
        report_counters(ctx, counters, "render.light_paths");
        return result;
    }

private:
    void splat(SplatBuffer& splats, std::size_t unit, const Vec2d& film, Color3 v, SampleCounters& c) const {
        if (!sanitize(v))
            ++c.invalid;
        else if (v != Color3(0.0))
            splats.splat(unit, film, v);
    }

    void trace(const Scene& scene, const Sensor& sensor, Sampler& sampler, SplatBuffer& splats, std::size_t unit,
               SampleCounters& c) const {
        const double u_sel = sampler.next_1d();
        const Vec2d u_pos = sampler.next_2d(), u_dir = sampler.next_2d(), u_lens0 = sampler.next_2d();
        auto [e, sel_pdf] = scene.sample_emitter(u_sel);
        if (!e) return;
        auto es = e->sample_emission(u_pos, u_dir);
        if (!es) return;
        const long max_len = m_max_depth < 0 ? std::numeric_limits<long>::max() : long(m_max_depth);

        // Path length 1: the emitter itself, seen by the camera (area emitters only; points cannot be seen).
        if (!m_hide_emitters && !es->delta_pos && (e->flags() & EmitterFlags::Surface)) {
            if (auto sd = sensor.sample_direct(es->ray.o, u_lens0)) {
                Color3 Le = e->eval(es->ray.o, es->n, es->uv, sd->d);
                if (Le != Color3(0.0)) {
                    SurfaceInteraction origin;
                    origin.p = es->ray.o;
                    origin.ng = es->n;
                    ++c.rays;
                    if (!scene.occluded(origin.spawn_to(sd->p)))
                        splat(splats, unit, sd->film,
                              Le * (std::abs(glm::dot(es->n, sd->d)) * sd->weight / (es->pdf_pos * sel_pdf)), c);
                }
            }
        }

        const BsdfContext bctx{TransportMode::Importance};
        Color3 beta = es->weight / sel_pdf;
        Ray ray = es->spawn_ray();
        ray.d = glm::normalize(ray.d);
        for (long depth = 1;; ++depth) {  // `depth` edges traced so far
            ++c.rays;
            auto hit = scene.intersect(ray);
            if (!hit) break;
            SurfaceInteraction si = scene.interaction(ray, *hit);
            const Bsdf& bsdf = *si.shape->bsdf();
            const double u_comp = sampler.next_1d();
            const Vec2d u_bsdf = sampler.next_2d();
            const double u_rr = sampler.next_1d();
            const Vec2d u_lens = sampler.next_2d();

            // Connect this vertex to the camera: a path of depth + 1 edges.
            if ((bsdf.flags() & BsdfFlags::Smooth) && depth + 1 <= max_len) {
                if (auto sd = sensor.sample_direct(si.p, u_lens)) {
                    Vec3d wo = si.to_local(sd->d);
                    Color3 f = bsdf.eval(bctx, si, wo) * shading_correction(si, si.wi, wo);
                    if (f != Color3(0.0)) {
                        ++c.rays;
                        if (!scene.occluded(si.spawn_to(sd->p)))
                            splat(splats, unit, sd->film, beta * f * sd->weight, c);
                    }
                }
            }
            if (depth + 2 > max_len) break;

            auto bs = bsdf.sample(bctx, si, u_comp, u_bsdf);
            if (!bs || bs->weight == Color3(0.0)) break;
            beta *= bs->weight * shading_correction(si, si.wi, bs->wo);
            if (depth >= m_rr_depth) {
                double q = std::min(0.95, std::max({beta.r, beta.g, beta.b}));
                if (!(u_rr < q)) break;
                beta /= q;
            }
            ray = si.spawn(si.to_world(bs->wo));
        }
    }

    int m_max_depth, m_rr_depth;
    bool m_hide_emitters;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::LightTracer, "integrator", "ptracer",
              "Light tracing: paths from the emitters, every vertex connected to the camera and splatted.",
              kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
              kelvin::param::integer("rr_depth", 5, "path length from which Russian roulette starts"),
              kelvin::param::boolean("hide_emitters", false, "do not render emitters seen directly"));
