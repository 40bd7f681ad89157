// bdpt: bidirectional path tracing (Veach and Guibas 1995; Veach 1997, Ch. 10). Each sample traces a camera
// subpath z_0..z_{t-1} and a light subpath y_0..y_{s-1} and combines every connection strategy (s, t) with
// multiple importance sampling (power heuristic). Strategies with t = 1 (light subpath vertices connected to the
// camera) land on other pixels and are splatted deterministically. Densities are kept per vertex in area
// measure (forward: as sampled; reverse: as the opposite subpath would have sampled it), and the MIS weight of
// a strategy is computed from ratios of those densities along the path, following the structure of pbrt-v3's
// implementation (Pharr, Jakob and Humphreys, "Physically Based Rendering", 3rd ed., Sec. 16.3).
//
// Paths are terminated by max_depth and by Russian roulette from rr_depth on (roulette is not part of the
// MIS densities; the estimate stays unbiased because every strategy's contribution is itself unbiased).
// Cameras: any sensor that supports connections (sample_direct, pdf_direction): the pinhole `perspective` and
// the `thinlens`, whose camera vertex is the lens point of the ray (its area density is the same for every
// strategy, so it cancels from the MIS weights; the directional density 1 / (A cos^3) holds from any lens point).
//
// Primary sample layout, in three sample streams (sampler.h) so that no subpath's numbers shift with another's
// length: the camera stream holds the film position and lens (0-3), then 4 per camera-subpath bounce; the light
// stream the emitter choice and emission (5), then 4 per light-subpath bounce; the connection stream 3 per
// next-event (s = 1) strategy and 2 per light-tracing (t = 1) strategy (the lens point), in the order the
// strategies are evaluated (t = 1..n_cam, s = 0..n_light).
//
// | parameter     | type    | default | meaning                                                  |
// |---------------|---------|---------|----------------------------------------------------------|
// | max_depth     | integer | -1      | longest path (in edges) that contributes; -1: unbounded  |
// | min_depth     | integer | 1       | shortest path (in edges) that contributes                 |
// | rr_depth      | integer | 5       | subpath length from which Russian roulette may stop it    |
// | hide_emitters | boolean | false   | emitters seen directly render black                       |
//
//     <integrator type="bdpt"><integer name="max_depth" value="8"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/film.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace kelvin {
namespace {

enum class VertexType : uint8_t { Camera, Light, Surface, Infinite };

struct Vertex {
    VertexType type = VertexType::Surface;
    Color3 beta{0.0};
    double pdf_fwd = 0, pdf_rev = 0;
    bool delta = false;
    Vec3d p{0.0}, ng{0.0};             // ng is zero for points (camera, point lights, infinite endpoints)
    SurfaceInteraction si;             // surface vertices
    const Emitter* emitter = nullptr;  // light vertices, and surface vertices that emit

    bool on_surface() const { return type == VertexType::Surface || (type == VertexType::Light && ng != Vec3d(0.0)); }
    bool is_light() const {
        return type == VertexType::Light || type == VertexType::Infinite || (type == VertexType::Surface && emitter);
    }
    bool is_infinite() const { return type == VertexType::Infinite; }
    bool is_delta_light() const {
        return type == VertexType::Light && emitter && (emitter->flags() & EmitterFlags::Delta);
    }
    /// Can a deterministic connection reach this vertex? (Not through a delta BSDF.)
    bool connectible() const {
        if (type == VertexType::Surface) return (si.shape->bsdf()->flags() & BsdfFlags::Smooth) != 0;
        if (type == VertexType::Light) return !(emitter->flags() & EmitterFlags::DeltaDirection);
        return true;
    }
};

constexpr double mis(double x) { return x * x; }  // power heuristic, exponent 2

class Bdpt final : public SamplingIntegrator {
public:
    static constexpr int MaxVertices = 64;  // hard cap per subpath (with max_depth -1, roulette ends paths first)

    explicit Bdpt(const Properties& props)
        : m_max_depth(int(props.get_int("max_depth", -1, MaxVertices - 2))),
          m_min_depth(int(props.get_int("min_depth", 1, 1 << 20))),
          m_rr_depth(int(props.get_int("rr_depth", 1, 1 << 20))),
          m_hide_emitters(props.get_bool("hide_emitters")) {
        if (m_max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
    }
    bool splats() const override { return true; }

    int sample_streams() const override { return SampleStreamCount; }

    void validate(const Scene& scene) const override {
        if (!scene.sensor()->supports_connections())
            throw InputError({}, fmt::format("bdpt needs a sensor that light paths can connect to (perspective, "
                                             "thinlens), not {}; use path",
                                             scene.sensor()->to_string()));
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& camera_ray, SampleCounters& c) const override {
        const Sensor& sensor = *scene.sensor();
        const int max_edges = m_max_depth < 0 ? MaxVertices - 1 : m_max_depth;
        // Per-thread vertex storage: no allocation and no 40 kB clear per sample. Every vertex a sample reads
        // is assigned before use (walk() assigns each vertex it adds; cam[0] and light[0] are reset below).
        thread_local std::array<Vertex, MaxVertices> cam, light;
        cam[0] = Vertex();
        light[0] = Vertex();

        // Camera subpath.
        Ray ray = camera_ray;
        ray.d = glm::normalize(ray.d);
        cam[0].type = VertexType::Camera;
        cam[0].beta = Color3(1.0);
        cam[0].p = ray.o;
        const double cam_pdf_dir = sensor.pdf_direction(ray.o, ray.d);
        const int n_cam =
            1 + walk(scene, sampler, ray, Color3(1.0), cam_pdf_dir, max_edges, TransportMode::Radiance, cam.data(), c);

        // Light subpath.
        sampler.set_stream(SampleStream::Light);
        int n_light = 0;
        auto [emitter, sel_pdf] = scene.sample_emitter(sampler.next_1d());
        const Vec2d u_pos = sampler.next_2d(), u_dir = sampler.next_2d();
        if (emitter && max_edges >= 1) {
            if (auto es = emitter->sample_emission(u_pos, u_dir)) {
                Vertex& y0 = light[0];
                y0.type = (emitter->flags() & EmitterFlags::Infinite) ? VertexType::Infinite : VertexType::Light;
                y0.emitter = emitter;
                y0.p = es->ray.o;
                y0.ng = (emitter->flags() & EmitterFlags::Surface) ? es->n : Vec3d(0.0);
                y0.beta = Color3(1.0);  // not used: s = 1 strategies resample the emitter
                y0.pdf_fwd = es->pdf_pos * sel_pdf;
                Ray lr = es->spawn_ray();
                lr.d = glm::normalize(lr.d);
                n_light = 1 + walk(scene, sampler, lr, es->weight / sel_pdf, es->pdf_dir, max_edges - 1,
                                   TransportMode::Importance, light.data(), c);
                if (y0.is_infinite()) {
                    // Infinite emitters start rays on a disk: y1's density is the disk's (area) density
                    // projected, and y0's is the directional density (pbrt-v3, Sec. 16.3.2).
                    if (n_light > 1) {
                        light[1].pdf_fwd = es->pdf_pos;
                        if (light[1].on_surface()) light[1].pdf_fwd *= std::abs(glm::dot(lr.d, light[1].ng));
                    }
                    y0.pdf_fwd = infinite_density(scene, -lr.d);  // direction from the scene to the light
                }
            }
        }

        // All strategies.
        sampler.set_stream(SampleStream::Connection);
        Color3 L(0.0);
        for (int t = 1; t <= n_cam; ++t)
            for (int s = 0; s <= n_light; ++s) {
                const int edges = s + t - 1;
                if (t == 1 && s == 0) continue;  // the camera (pinhole or lens) is not in the scene: never hit
                // Emitters seen directly come from (s=0, t=2) alone, exactly and noise-free; (1, 1) would count
                // them twice (pbrt makes the same choice, and mis_weight() returns 1 for s + t == 2).
                if (t == 1 && s == 1) continue;
                if (edges < std::max(1, m_min_depth) || edges > max_edges) continue;
                if (m_hide_emitters && t + s == 2) continue;
                Vec2d film;
                Color3 v = connect(scene, sensor, light.data(), cam.data(), s, t, sampler, film, c);
                if (v == Color3(0.0)) continue;
                if (!sanitize(v)) {
                    ++c.invalid;
                    continue;
                }
                if (t == 1)
                    c.splats->splat(film, v);
                else
                    L += v;
            }
        return L;
    }

private:
    // Random walk from `ray`; fills path[1..] and returns the number of vertices added.
    int walk(const Scene& scene, Sampler& sampler, Ray ray, Color3 beta, double pdf_dir, int max_edges,
             TransportMode mode, Vertex* path, SampleCounters& c) const {
        if (max_edges <= 0 || !(pdf_dir > 0)) return 0;
        const BsdfContext ctx{mode};
        int n = 0;
        double pdf_fwd = pdf_dir;
        for (int depth = 0;; ++depth) {
            const double u_comp = sampler.next_1d();
            const Vec2d u_bsdf = sampler.next_2d();
            const double u_rr = sampler.next_1d();
            ++c.rays;
            auto hit = scene.intersect(ray);
            Vertex& prev = path[n];
            Vertex& v = path[n + 1];
            v = Vertex();
            if (!hit) {
                // A camera path escaping the scene ends on the environment (if any), as a light vertex.
                if (mode == TransportMode::Radiance && !scene.environment_emitters().empty()) {
                    v.type = VertexType::Infinite;
                    v.beta = beta;
                    v.p = ray.o + ray.d;  // a direction: only (p - prev.p) is ever used
                    v.pdf_fwd = pdf_fwd;  // solid angle: infinite vertices are never converted to area
                    ++n;
                }
                break;
            }
            v.type = VertexType::Surface;
            v.si = scene.interaction(ray, *hit);
            v.p = v.si.p;
            v.ng = v.si.ng;
            v.emitter = v.si.shape->emitter();
            v.beta = beta;
            v.pdf_fwd = convert_density(pdf_fwd, prev, v);
            ++n;
            if (n >= max_edges || n + 1 >= MaxVertices) break;

            const Bsdf& bsdf = *v.si.shape->bsdf();
            auto bs = bsdf.sample(ctx, v.si, u_comp, u_bsdf);
            if (!bs || bs->weight == Color3(0.0)) break;
            Color3 w = bs->weight;
            if (mode == TransportMode::Importance) w *= shading_correction(v.si, v.si.wi, bs->wo);
            beta *= w;
            double pdf_rev;
            if (bs->sampled & BsdfFlags::Delta) {
                v.delta = true;
                pdf_fwd = pdf_rev = 0;
            } else {
                pdf_fwd = bs->pdf;
                SurfaceInteraction rev = v.si;
                rev.wi = bs->wo;
                pdf_rev = bsdf.pdf(ctx, rev, v.si.wi);
            }
            prev.pdf_rev = convert_density(pdf_rev, v, prev);
            if (depth + 1 >= m_rr_depth) {
                double q = std::min(0.95, std::max({beta.r, beta.g, beta.b}));
                if (!(u_rr < q)) break;
                beta /= q;
            }
            ray = v.si.spawn(v.si.to_world(bs->wo));
            ray.d = glm::normalize(ray.d);
        }
        return n;
    }

    // Solid-angle density at `from` towards `to`, converted to area density at `to`.
    static double convert_density(double pdf, const Vertex& from, const Vertex& to) {
        if (to.is_infinite()) return pdf;
        Vec3d w = to.p - from.p;
        double d2 = glm::dot(w, w);
        if (!(d2 > 0)) return 0.0;
        double inv = 1.0 / d2;
        if (to.on_surface()) pdf *= std::abs(glm::dot(to.ng, w * std::sqrt(inv)));
        return pdf * inv;
    }

    static double infinite_density(const Scene& scene, const Vec3d& d_from_scene_to_light_dir) {
        // Density with which emitter sampling picks direction d among the infinite emitters.
        double pdf = 0;
        for (const Emitter* e : scene.environment_emitters())
            pdf += scene.emitter_pdf(e) * e->pdf_direct(Vec3d(0.0), Vec3d(0.0), Vec3d(0.0), d_from_scene_to_light_dir);
        return pdf;
    }

    // Area density with which `v` (a light vertex, or an emitting surface hit) emits towards `next`.
    double pdf_light(const Scene& scene, const Vertex& v, const Vertex& next) const {
        Vec3d w = next.p - v.p;
        double d2 = glm::dot(w, w);
        if (!(d2 > 0)) return 0.0;
        w /= std::sqrt(d2);
        double pdf;
        if (v.is_infinite()) {
            const Emitter* e = v.emitter ? v.emitter : scene.environment_emitters().front();
            pdf = e->pdf_emission(Vec3d(0.0), Vec3d(0.0), -w).first;  // disk density
        } else {
            pdf = v.emitter->pdf_emission(v.p, v.ng, w).second / d2;
        }
        if (next.on_surface()) pdf *= std::abs(glm::dot(next.ng, w));
        return pdf;
    }

    // Density of choosing `v` as a light-subpath origin (towards `next`).
    double pdf_light_origin(const Scene& scene, const Vertex& v, const Vertex& next) const {
        Vec3d w = next.p - v.p;
        double l = glm::length(w);
        if (!(l > 0)) return 0.0;
        w /= l;
        if (v.is_infinite()) return infinite_density(scene, -w);
        return scene.emitter_pdf(v.emitter) * v.emitter->pdf_emission(v.p, v.ng, w).first;
    }

    // Area density with which vertex `v` (reached from `prev`) samples `next`.
    double pdf(const Scene& scene, const Sensor& sensor, const Vertex& v, const Vertex* prev,
               const Vertex& next) const {
        if (v.type == VertexType::Light || v.type == VertexType::Infinite) return pdf_light(scene, v, next);
        Vec3d wn = next.p - v.p;
        double l = glm::length(wn);
        if (!(l > 0)) return 0.0;
        wn /= l;
        double p;
        if (v.type == VertexType::Camera) {
            p = sensor.pdf_direction(v.p, wn);
        } else {
            SurfaceInteraction si = v.si;
            si.wi = si.to_local(glm::normalize(prev->p - v.p));
            p = v.si.shape->bsdf()->pdf(BsdfContext{}, si, si.to_local(wn));
        }
        return convert_density(p, v, next);
    }

    // f * |cos| at `v` towards `next`, `v` having been reached from its own subpath's previous vertex.
    static Color3 f(const Vertex& v, const Vertex& next, TransportMode mode) {
        Vec3d wo = v.si.to_local(glm::normalize(next.p - v.p));
        Color3 r = v.si.shape->bsdf()->eval(BsdfContext{mode}, v.si, wo);
        if (mode == TransportMode::Importance) r *= shading_correction(v.si, v.si.wi, wo);
        return r;
    }

    static double geometry_visible(const Scene& scene, const Vertex& a, const Vertex& b, SampleCounters& c) {
        // 1 / d^2 if unoccluded (cosines are inside f()), 0 otherwise.
        ++c.rays;
        Ray r = a.si.spawn_to(b.p);
        if (scene.occluded(r)) return 0.0;
        Vec3d d = b.p - a.p;
        return 1.0 / glm::dot(d, d);
    }

    Color3 connect(const Scene& scene, const Sensor& sensor, Vertex* light, Vertex* cam, int s, int t, Sampler& sampler,
                   Vec2d& film, SampleCounters& c) const {
        Color3 L(0.0);
        Vertex sampled;  // the resampled endpoint for s = 1 or t = 1
        const Vertex& pt = cam[t - 1];
        if (s == 0) {
            // The camera subpath hit an emitter.
            if (!pt.is_light()) return L;
            const Vertex& prev = cam[t - 2];
            Vec3d w = glm::normalize(prev.p - pt.p);
            if (pt.is_infinite()) {
                for (const Emitter* e : scene.environment_emitters()) L += e->eval(prev.p, Vec3d(0.0), w);
            } else {
                L = pt.emitter->eval(pt.p, pt.ng, w);
            }
            L *= pt.beta;
        } else if (t == 1) {
            // Connect the light subpath's last vertex to the camera (a point on the lens, for a thin lens).
            const Vertex& qs = light[s - 1];
            const Vec2d u_lens = sampler.next_2d();  // drawn whatever happens next: the layout stays fixed
            if (!qs.connectible() || qs.is_infinite()) return L;
            auto sd = sensor.sample_direct(qs.p, u_lens);
            if (!sd) return L;
            sampled.type = VertexType::Camera;
            sampled.p = sd->p;
            sampled.beta = Color3(sd->weight);
            Color3 contrib = qs.beta * f(qs, sampled, TransportMode::Importance);  // s >= 2 here
            if (contrib == Color3(0.0)) return L;
            ++c.rays;
            SurfaceInteraction from;
            from.p = qs.p;
            from.ng = qs.ng == Vec3d(0.0) ? sd->d : qs.ng;
            if (scene.occluded(from.spawn_to(sd->p))) return L;
            L = contrib * sd->weight;
            film = sd->film;
        } else if (s == 1) {
            // Next-event estimation: sample a point on an emitter.
            const double u_sel = sampler.next_1d();  // drawn whatever happens next: the layout stays fixed
            const Vec2d u = sampler.next_2d();
            if (!pt.connectible() || pt.type != VertexType::Surface) return L;
            auto [e, sel] = scene.sample_emitter(u_sel);
            if (!e) return L;
            auto ds = e->sample_direct(pt.p, u);
            if (!ds || !(ds->pdf > 0)) return L;
            sampled.type = (e->flags() & EmitterFlags::Infinite) ? VertexType::Infinite : VertexType::Light;
            sampled.emitter = e;
            sampled.p = ds->dist == Inf ? pt.p + ds->d : ds->p;
            sampled.ng = (e->flags() & EmitterFlags::Surface) ? ds->n : Vec3d(0.0);
            sampled.beta = ds->weight / sel;
            sampled.pdf_fwd = pdf_light_origin(scene, sampled, pt);
            Vec3d wo = pt.si.to_local(ds->d);
            Color3 fv = pt.si.shape->bsdf()->eval(BsdfContext{}, pt.si, wo);
            if (fv == Color3(0.0)) return L;
            ++c.rays;
            Ray shadow = ds->dist == Inf ? pt.si.spawn(ds->d) : pt.si.spawn_to(ds->p);
            if (scene.occluded(shadow)) return L;
            L = pt.beta * fv * sampled.beta;
        } else {
            const Vertex& qs = light[s - 1];
            if (!qs.connectible() || !pt.connectible() || qs.is_infinite() || pt.is_infinite()) return L;
            if (qs.type != VertexType::Surface || pt.type != VertexType::Surface) return L;
            Color3 fq = f(qs, pt, TransportMode::Importance), fp = f(pt, qs, TransportMode::Radiance);
            if (fq == Color3(0.0) || fp == Color3(0.0)) return L;
            double g = geometry_visible(scene, pt, qs, c);
            if (g == 0) return L;
            L = qs.beta * fq * fp * pt.beta * g;
        }
        if (L == Color3(0.0)) return L;
        return L * mis_weight(scene, sensor, light, cam, sampled, s, t);
    }

    double mis_weight(const Scene& scene, const Sensor& sensor, Vertex* light, Vertex* cam, const Vertex& sampled,
                      int s, int t) const {
        if (s + t == 2) return 1.0;
        // Work on copies of the (at most four) vertices whose densities change for this strategy.
        std::array<Vertex, 4> saved;
        Vertex* touched[4] = {nullptr, nullptr, nullptr, nullptr};
        int nt = 0;
        auto touch = [&](Vertex* v) {
            for (int i = 0; i < nt; ++i)
                if (touched[i] == v) return;
            saved[nt] = *v;
            touched[nt++] = v;
        };
        if (s == 1) touch(&light[0]), light[0] = sampled;
        if (t == 1) touch(&cam[0]), cam[0] = sampled;
        Vertex* qs = s > 0 ? &light[s - 1] : nullptr;
        Vertex* pt = &cam[t - 1];
        Vertex* qs_minus = s > 1 ? &light[s - 2] : nullptr;
        Vertex* pt_minus = t > 1 ? &cam[t - 2] : nullptr;
        touch(pt);
        if (qs) touch(qs);
        if (pt_minus) touch(pt_minus);
        if (qs_minus) touch(qs_minus);
        pt->delta = false;
        if (qs) qs->delta = false;

        pt->pdf_rev = s > 0 ? pdf(scene, sensor, *qs, qs_minus, *pt) : pdf_light_origin(scene, *pt, *pt_minus);
        if (pt_minus)
            pt_minus->pdf_rev = s > 0 ? pdf(scene, sensor, *pt, qs, *pt_minus) : pdf_light(scene, *pt, *pt_minus);
        if (qs) qs->pdf_rev = pdf(scene, sensor, *pt, pt_minus, *qs);
        if (qs_minus) qs_minus->pdf_rev = pdf(scene, sensor, *qs, pt, *qs_minus);

        auto remap = [](double x) { return x != 0 ? x : 1.0; };
        double sum = 0, ri = 1;
        for (int i = t - 1; i > 0; --i) {
            ri *= mis(remap(cam[i].pdf_rev)) / mis(remap(cam[i].pdf_fwd));
            if (!cam[i].delta && !cam[i - 1].delta) sum += ri;
        }
        ri = 1;
        for (int i = s - 1; i >= 0; --i) {
            ri *= mis(remap(light[i].pdf_rev)) / mis(remap(light[i].pdf_fwd));
            bool delta_before = i > 0 ? light[i - 1].delta : light[0].is_delta_light();
            if (!light[i].delta && !delta_before) sum += ri;
        }
        for (int i = nt - 1; i >= 0; --i) *touched[i] = saved[i];
        return 1.0 / (1.0 + sum);
    }

    int m_max_depth, m_min_depth, m_rr_depth;
    bool m_hide_emitters;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(
    kelvin::Bdpt, "integrator", "bdpt",
    "Bidirectional path tracing: all (s, t) connection strategies with MIS; light-tracing strategies splatted.",
    kelvin::param::integer("max_depth", -1, "longest contributing path in edges (-1: unbounded)"),
    kelvin::param::integer("min_depth", 1, "shortest contributing path in edges"),
    kelvin::param::integer("rr_depth", 5, "subpath length from which Russian roulette starts"),
    kelvin::param::boolean("hide_emitters", false, "emitters seen directly render black"));
