// The bidirectional path-sampling core: see include/kelvin/render/bidirectional.h.
#include <kelvin/render/bidirectional.h>
#include <kelvin/render/film.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <array>
#include <cmath>

namespace kelvin {

bool PathVertex::on_surface() const {
    return type == PathVertexType::Surface || (type == PathVertexType::Light && ng != Vec3d(0.0));
}
bool PathVertex::is_light() const {
    return type == PathVertexType::Light || type == PathVertexType::Infinite ||
           (type == PathVertexType::Surface && emitter);
}
bool PathVertex::is_delta_light() const {
    // A directional light starts its light subpaths at an Infinite vertex: no ray can hit it either.
    return (type == PathVertexType::Light || type == PathVertexType::Infinite) && emitter &&
           (emitter->flags() & EmitterFlags::Delta);
}
bool PathVertex::connectible() const {
    if (type == PathVertexType::Surface) return smooth;
    if (type == PathVertexType::Light) return !(emitter->flags() & EmitterFlags::DeltaDirection);
    return true;
}

namespace {

// Solid-angle density at `from` towards `to`, converted to area density at `to`.
double convert_density(double pdf, const PathVertex& from, const PathVertex& to) {
    if (to.is_infinite()) return pdf;
    Vec3d w = to.p - from.p;
    double d2 = glm::dot(w, w);
    if (!(d2 > 0)) return 0.0;
    double inv = 1.0 / d2;
    if (to.on_surface()) pdf *= std::abs(glm::dot(to.ng, w * std::sqrt(inv)));
    return pdf * inv;
}

double infinite_density(const Scene& scene, const Vec3d& d_from_scene_to_light_dir) {
    // Density with which emitter sampling picks direction d among the infinite emitters.
    double pdf = 0;
    for (const Emitter* e : scene.environment_emitters())
        pdf += scene.emitter_pdf(e) * e->pdf_direct({.d = d_from_scene_to_light_dir});
    return pdf;
}

// Area density with which `v` (a light vertex, or an emitting surface hit) emits towards `next`.
double pdf_light(const Scene& scene, const PathVertex& v, const PathVertex& next) {
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
double pdf_light_origin(const Scene& scene, const PathVertex& v, const PathVertex& next) {
    Vec3d w = next.p - v.p;
    double l = glm::length(w);
    if (!(l > 0)) return 0.0;
    w /= l;
    if (v.is_infinite()) return infinite_density(scene, -w);
    return scene.emitter_pdf(v.emitter) * v.emitter->pdf_emission(v.p, v.ng, w).first;
}

// The density, per solid angle at `v`, of a delta lobe chosen with discrete probability `prob` towards unit
// direction `w`: Veach's (1997, Sec. 10.3.5), the probability per projected solid angle, so that the area density
// of the next vertex is prob times the edge's geometry factor. Its delta function is common to every strategy that
// can sample the path and cancels in their ratios.
double delta_density(double prob, const PathVertex& v, const Vec3d& w) { return prob * std::abs(glm::dot(v.ng, w)); }

// Area density with which vertex `v` (reached from `prev`) samples `next`. The BSDF is asked with v.si.wi set to
// the direction towards `prev` (restored before returning: no copy of the interaction). A vertex where the subpath
// sampled a delta lobe (v.delta) gives that lobe's density towards `next` (the densities a subpath stores, here
// from the vertices' positions); next to a connection the joined vertices are never delta.
double pdf(const Scene& scene, const Sensor& sensor, PathVertex& v, const PathVertex* prev, const PathVertex& next) {
    if (v.type == PathVertexType::Light || v.type == PathVertexType::Infinite) return pdf_light(scene, v, next);
    Vec3d wn = next.p - v.p;
    double l = glm::length(wn);
    if (!(l > 0)) return 0.0;
    wn /= l;
    double p;
    if (v.type == PathVertexType::Camera) {
        p = sensor.pdf_direction(v.p, wn);
    } else if (v.delta) {
        p = delta_density(v.pdf_delta, v, wn);
    } else {
        const Vec3d wi = v.si.wi;
        v.si.wi = v.si.to_local(glm::normalize(prev->p - v.p));
        p = v.si.shape->bsdf()->pdf(BsdfContext{}, v.si, v.si.to_local(wn));
        v.si.wi = wi;
    }
    return convert_density(p, v, next);
}

// f * |cos| at `v` towards `next`, `v` having been reached from its own subpath's previous vertex.
Color3 f(const PathVertex& v, const PathVertex& next, TransportMode mode) {
    Vec3d wo = v.si.to_local(glm::normalize(next.p - v.p));
    Color3 r = v.si.shape->bsdf()->eval(BsdfContext{mode}, v.si, wo);
    if (mode == TransportMode::Importance) r *= shading_correction(v.si, v.si.wi, wo);
    return r;
}

// Whether strategy (s, t) can join these subpaths at all, before visibility and BSDF values: for s = 0 the camera
// subpath must end on an emitter that rays can hit; the two vertices joined must have a smooth BSDF component (a
// light vertex: no delta direction), and neither may lie at infinity except the emitter of s = 1.
bool joinable(const PathVertex* light, const PathVertex* cam, int s, int t) {
    const PathVertex& pt = cam[t - 1];
    if (s == 0) return pt.is_light() && !pt.is_delta_light();
    if (t == 1) {
        const PathVertex& qs = light[s - 1];
        return qs.connectible() && !qs.is_infinite();
    }
    if (s == 1) return pt.connectible() && pt.type == PathVertexType::Surface;
    const PathVertex& qs = light[s - 1];
    if (!qs.connectible() || !pt.connectible() || qs.is_infinite() || pt.is_infinite()) return false;
    return qs.type == PathVertexType::Surface && pt.type == PathVertexType::Surface;
}

// (p_nee / p_origin)^2 for the light vertex y0 of a path whose next vertex is y1: p_nee, the area density with which
// next-event estimation from y1 picks y0 (Emitter::pdf_direct converted to area), over p_origin, y0's density as a
// light subpath's origin, the density the subpaths and light_endpoint() store for it. The two are the same, and this
// is 1 without computing either, where the emitter samples by area; they differ for a sphere light, whose next-event
// estimation samples the cone it subtends: only the strategy (1, t) samples y0 with p_nee.
double nee_ratio2(const Scene& scene, const PathVertex& y0, const PathVertex& y1) {
    const Emitter* e = y0.emitter;
    if (!e || y0.is_infinite() || !y0.on_surface() || !e->direct_differs_from_emission()) return 1.0;
    Vec3d d = y0.p - y1.p;
    const double d2 = glm::dot(d, d);
    if (!(d2 > 0)) return 0.0;
    d /= std::sqrt(d2);
    const double origin = e->pdf_emission(y0.p, y0.ng, -d).first;
    const double nee = e->pdf_direct({y1.p, y0.p, y0.ng, d}) * std::abs(glm::dot(y0.ng, d)) / d2;
    return origin > 0 ? power_heuristic_ratio(nee, origin) : 0.0;
}

// The light vertex of a next-event (s = 1) strategy: point `p` (for infinite emitters: pt.p plus the unit direction
// towards the emitter) with normal `n` on emitter `e`, connected to `pt`; its forward density is that of the
// emitter as a light-subpath origin, which is what the other strategies see at x_0.
PathVertex light_endpoint(const Scene& scene, const Emitter* e, const Vec3d& p, const Vec3d& n, const PathVertex& pt) {
    PathVertex v;
    v.type = (e->flags() & EmitterFlags::Infinite) ? PathVertexType::Infinite : PathVertexType::Light;
    v.emitter = e;
    v.p = p;
    v.ng = (e->flags() & EmitterFlags::Surface) ? n : Vec3d(0.0);
    v.pdf_fwd = pdf_light_origin(scene, v, pt);
    return v;
}

// Sets the reverse densities of the (at most four) vertices next to the connection of strategy (s, t): qs = y_{s-1}
// and qs_minus = y_{s-2} (null where s is too small), pt = z_{t-1} and pt_minus = z_{t-2} (null for t = 1), with the
// resampled endpoint in place of y_0 for s = 1 and of z_0 for t = 1; clears the delta flags of the two joined, as that
// strategy sees them.
void connection_densities(const Scene& scene, const Sensor& sensor, PathVertex* qs, PathVertex* pt,
                          PathVertex* qs_minus, PathVertex* pt_minus) {
    pt->delta = false;
    if (qs) qs->delta = false;

    pt->pdf_rev = qs ? pdf(scene, sensor, *qs, qs_minus, *pt) : pdf_light_origin(scene, *pt, *pt_minus);
    if (pt_minus) pt_minus->pdf_rev = qs ? pdf(scene, sensor, *pt, qs, *pt_minus) : pdf_light(scene, *pt, *pt_minus);
    if (qs) qs->pdf_rev = pdf(scene, sensor, *pt, pt_minus, *qs);
    if (qs_minus) qs_minus->pdf_rev = pdf(scene, sensor, *qs, pt, *qs_minus);
}

// The same for strategy (s, t) on whole subpaths, their endpoints as sampled (s != 1, t != 1).
void connection_densities(const Scene& scene, const Sensor& sensor, PathVertex* light, PathVertex* cam, int s, int t) {
    connection_densities(scene, sensor, s > 0 ? &light[s - 1] : nullptr, &cam[t - 1], s > 1 ? &light[s - 2] : nullptr,
                         t > 1 ? &cam[t - 2] : nullptr);
}

double geometry_visible(const Scene& scene, const PathVertex& a, const PathVertex& b, SampleCounters& c) {
    // 1 / d^2 if unoccluded (cosines are inside f()), 0 otherwise.
    ++c.rays;
    Ray r = a.si.spawn_to(b.p);
    if (scene.occluded(r)) return 0.0;
    Vec3d d = b.p - a.p;
    return 1.0 / glm::dot(d, d);
}

}  // namespace

int BidirectionalPaths::camera_subpath(const Scene& scene, Sampler& sampler, const Ray& camera_ray, int max_bounces,
                                       PathVertex* cam, SampleCounters& c) const {
    const Sensor& sensor = *scene.sensor();
    cam[0] = PathVertex();
    Ray ray = camera_ray;
    ray.d = glm::normalize(ray.d);
    cam[0].type = PathVertexType::Camera;
    cam[0].beta = Color3(1.0);
    cam[0].p = ray.o;
    const double pdf_dir = sensor.pdf_direction(ray.o, ray.d);
    return 1 + walk(scene, sampler, ray, Color3(1.0), pdf_dir, max_bounces, TransportMode::Radiance, cam, c);
}

int BidirectionalPaths::light_subpath(const Scene& scene, Sampler& sampler, int max_bounces, PathVertex* light,
                                      SampleCounters& c) const {
    light[0] = PathVertex();
    auto [emitter, sel_pdf] = scene.sample_emitter(sampler.next_1d());
    const Vec2d u_pos = sampler.next_2d(), u_dir = sampler.next_2d();
    if (!emitter) return 0;
    auto es = emitter->sample_emission(u_pos, u_dir);
    if (!es) return 0;
    PathVertex& y0 = light[0];
    y0.type = (emitter->flags() & EmitterFlags::Infinite) ? PathVertexType::Infinite : PathVertexType::Light;
    y0.emitter = emitter;
    y0.p = es->ray.o;
    y0.ng = (emitter->flags() & EmitterFlags::Surface) ? es->n : Vec3d(0.0);
    y0.beta = Color3(1.0);  // not used: s = 1 strategies resample the emitter, (1, 1) divides by pdf_fwd
    y0.si.uv = es->uv;      // where (1, 1) reads a textured radiance
    y0.pdf_fwd = es->pdf_pos * sel_pdf;
    Ray lr = es->spawn_ray();
    lr.d = glm::normalize(lr.d);
    const int n = 1 + walk(scene, sampler, lr, es->weight / sel_pdf, es->pdf_dir, max_bounces,
                           TransportMode::Importance, light, c);
    if (y0.is_infinite()) {
        // Infinite emitters start rays on a disk: y1's density is the disk's (area) density projected, and
        // y0's is the directional density (pbrt-v3, Sec. 16.3.2).
        if (n > 1) {
            light[1].pdf_fwd = es->pdf_pos;
            if (light[1].on_surface()) light[1].pdf_fwd *= std::abs(glm::dot(lr.d, light[1].ng));
        }
        y0.pdf_fwd = infinite_density(scene, -lr.d);  // direction from the scene to the light
    }
    return n;
}

// Random walk from `ray`; fills path[1..] and returns the number of vertices added.
int BidirectionalPaths::walk(const Scene& scene, Sampler& sampler, Ray ray, Color3 beta, double pdf_dir, int max_edges,
                             TransportMode mode, PathVertex* path, SampleCounters& c) const {
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
        PathVertex& prev = path[n];
        PathVertex& v = path[n + 1];
        if (!hit) {
            // A camera path escaping the scene ends on the environment (if any), as a light vertex.
            if (mode == TransportMode::Radiance && !scene.environment_emitters().empty()) {
                v = PathVertex();
                v.type = PathVertexType::Infinite;
                v.beta = beta;
                v.p = ray.o + ray.d;  // a direction: only (p - prev.p) is ever used
                v.pdf_fwd = pdf_fwd;  // solid angle: infinite vertices are never converted to area
                ++n;
            }
            break;
        }
        // Every field assigned (no clear of the whole vertex first).
        v.type = PathVertexType::Surface;
        v.si = scene.interaction(ray, *hit);
        v.p = v.si.p;
        v.ng = v.si.ng;
        v.emitter = v.si.shape->emitter();
        v.beta = beta;
        v.pdf_rev = 0;
        v.delta = false;
        v.pdf_delta = 0;
        const Bsdf& bsdf = *v.si.shape->bsdf();
        v.smooth = (bsdf.flags() & BsdfFlags::Smooth) != 0;
        v.pdf_fwd = convert_density(pdf_fwd, prev, v);
        ++n;
        if (n >= max_edges || n + 1 >= MaxVertices) break;

        auto bs = bsdf.sample(ctx, v.si, u_comp, u_bsdf);
        if (!bs || bs->weight == Color3(0.0)) break;
        Color3 w = bs->weight;
        if (mode == TransportMode::Importance) w *= shading_correction(v.si, v.si.wi, bs->wo);
        beta *= w;
        double pdf_rev;
        if (bs->sampled & BsdfFlags::Delta) {
            // Veach's densities (delta_density): the lobe's probability, the same both ways, per projected solid
            // angle; the area conversion at the neighbours adds the rest of each edge's geometry factor.
            v.delta = true;
            v.pdf_delta = bs->pdf;
            pdf_fwd = delta_density(bs->pdf, v, glm::normalize(v.si.to_world(bs->wo)));
            pdf_rev = delta_density(bs->pdf, v, ray.d);
        } else {
            pdf_fwd = bs->pdf;
            const Vec3d wi = v.si.wi;  // the reverse direction's density: wi and wo swapped in place
            v.si.wi = bs->wo;
            pdf_rev = bsdf.pdf(ctx, v.si, wi);
            v.si.wi = wi;
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

Color3 BidirectionalPaths::connect(const Scene& scene, PathVertex* light, PathVertex* cam, int s, int t,
                                   Sampler& sampler, Vec2d& film, SampleCounters& c) const {
    // Most connections of a sample contribute nothing (the BSDF is zero towards the other vertex, or the segment is
    // blocked): each case returns as early as it can, and only the cases that resample an endpoint build one.
    const Sensor& sensor = *scene.sensor();
    Color3 L(0.0);
    const PathVertex& pt = cam[t - 1];
    if (s == 0) {
        // The camera subpath hit an emitter.
        if (!joinable(light, cam, s, t)) return L;
        const PathVertex& prev = cam[t - 2];
        Vec3d w = glm::normalize(prev.p - pt.p);
        if (pt.is_infinite()) {
            for (const Emitter* e : scene.environment_emitters()) L += e->eval(prev.p, Vec3d(0.0), Vec2d(0.0), w);
        } else {
            L = pt.emitter->eval(pt.p, pt.ng, pt.si.uv, w);
        }
        L *= pt.beta;
        if (L == Color3(0.0)) return L;
        return L * mis_weight(scene, sensor, light, cam, nullptr, s, t);
    }
    if (t == 1) {
        // Connect the light subpath's last vertex to the camera (a point on the lens, for a thin lens).
        const PathVertex& qs = light[s - 1];
        const Vec2d u_lens = sampler.next_2d();  // drawn whatever happens next: the layout stays fixed
        if (!joinable(light, cam, s, t)) return L;
        // (1, 1): the light image, from a point on an area emitter only.
        if (s == 1 && !(m_light_image && qs.type == PathVertexType::Light && qs.on_surface() && qs.pdf_fwd > 0))
            return L;
        auto sd = sensor.sample_direct(qs.p, u_lens);
        if (!sd) return L;
        PathVertex sampled;
        sampled.type = PathVertexType::Camera;
        sampled.p = sd->p;
        sampled.beta = Color3(sd->weight);
        Color3 contrib;
        if (s == 1) {
            // The emitted radiance towards the camera, |cos| at the emitter, over the origin's area density.
            const Vec3d w = glm::normalize(sampled.p - qs.p);
            contrib = qs.emitter->eval(qs.p, qs.ng, qs.si.uv, w) * (std::abs(glm::dot(qs.ng, w)) / qs.pdf_fwd);
        } else {
            contrib = qs.beta * f(qs, sampled, TransportMode::Importance);
        }
        if (contrib == Color3(0.0)) return L;
        ++c.rays;
        SurfaceInteraction from;
        from.p = qs.p;
        from.ng = qs.ng == Vec3d(0.0) ? sd->d : qs.ng;
        if (scene.occluded(from.spawn_to(sd->p))) return L;
        L = contrib * sd->weight;
        film = sd->film;
        if (L == Color3(0.0)) return L;
        return L * mis_weight(scene, sensor, light, cam, &sampled, s, t);
    }
    if (s == 1) {
        // Next-event estimation: sample a point on an emitter.
        const double u_sel = sampler.next_1d();  // drawn whatever happens next: the layout stays fixed
        const Vec2d u = sampler.next_2d();
        if (!joinable(light, cam, s, t)) return L;
        auto [e, sel] = scene.sample_emitter(u_sel);
        if (!e) return L;
        auto ds = e->sample_direct(pt.p, u);
        if (!ds || !(ds->pdf > 0)) return L;
        Vec3d wo = pt.si.to_local(ds->d);
        Color3 fv = pt.si.shape->bsdf()->eval(BsdfContext{}, pt.si, wo);
        if (fv == Color3(0.0)) return L;
        ++c.rays;
        Ray shadow = ds->dist == Inf ? pt.si.spawn(ds->d) : pt.si.spawn_to(ds->p);
        if (scene.occluded(shadow)) return L;
        PathVertex sampled = light_endpoint(scene, e, ds->dist == Inf ? pt.p + ds->d : ds->p, ds->n, pt);
        sampled.beta = ds->weight / sel;
        L = pt.beta * fv * sampled.beta;
        if (L == Color3(0.0)) return L;
        return L * mis_weight(scene, sensor, light, cam, &sampled, s, t);
    }
    // Two subpath vertices joined: the BSDF on the light side first, the camera side only if that is not zero.
    const PathVertex& qs = light[s - 1];
    if (!joinable(light, cam, s, t)) return L;
    Color3 fq = f(qs, pt, TransportMode::Importance);
    if (fq == Color3(0.0)) return L;
    Color3 fp = f(pt, qs, TransportMode::Radiance);
    if (fp == Color3(0.0)) return L;
    double g = geometry_visible(scene, pt, qs, c);
    if (g == 0) return L;
    L = qs.beta * fq * fp * pt.beta * g;
    if (L == Color3(0.0)) return L;
    return L * mis_weight(scene, sensor, light, cam, nullptr, s, t);
}

double BidirectionalPaths::mis_weight(const Scene& scene, const Sensor& sensor, PathVertex* light, PathVertex* cam,
                                      PathVertex* sampled, int s, int t) const {
    // An emitter seen directly: (0, 2) alone, or with the light image (1, 1) where that can sample it (an area
    // emitter; not the environment, not a delta light).
    if (s + t == 2 && !(m_light_image && (s == 1 || cam[1].on_surface()))) return 1.0;
    // The (at most four) vertices whose densities change for this strategy, with the resampled endpoint (s = 1:
    // y_0, t = 1: z_0) in place of the subpath's own; the subpaths' reverse densities and delta flags are saved and
    // restored (the endpoint is the caller's copy). (1, 1) resamples the camera only: y_0 is the light subpath's.
    const bool own_y0 = s == 1 && t == 1;
    PathVertex* qs = s == 1 && !own_y0 ? sampled : s >= 1 ? &light[s - 1] : nullptr;
    PathVertex* pt = t == 1 ? sampled : &cam[t - 1];
    PathVertex* qs_minus = s > 1 ? &light[s - 2] : nullptr;
    PathVertex* pt_minus = t > 1 ? &cam[t - 2] : nullptr;
    struct Saved {
        PathVertex* v;
        double pdf_rev;
        bool delta;
    };
    std::array<Saved, 4> saved;
    int nt = 0;
    for (PathVertex* v : {pt, qs, pt_minus, qs_minus})
        if (v && v != sampled) saved[std::size_t(nt++)] = {v, v->pdf_rev, v->delta};
    connection_densities(scene, sensor, qs, pt, qs_minus, pt_minus);

    // A density of 0 is taken as 1 (pbrt's remap). Specular vertices no longer give any (the walk stores Veach's
    // densities there); what remains is a reverse BSDF density of 0 (shading normals, float geometry), kept as it
    // was so that images without specular vertices do not change.
    auto remap = [](double x) { return x != 0 ? x : 1.0; };
    // Strategy (1, t') (t' >= 2: paths of three vertices or more) samples the light vertex by next-event estimation,
    // the others by the densities stored (nee_ratio2): its term, or for s = 1 every other, carries the ratio.
    double nee2 = 1;
    if (s + t >= 3) {
        if (s == 0)
            nee2 = nee_ratio2(scene, cam[t - 1], cam[t - 2]);
        else if (s == 1)
            nee2 = nee_ratio2(scene, *sampled, cam[t - 1]);
        else
            nee2 = nee_ratio2(scene, light[0], light[1]);
    }
    double sum = 0, ri = 1;
    for (int i = t - 1; i > 0; --i) {
        ri *= power_heuristic_ratio(remap(cam[i].pdf_rev), remap(cam[i].pdf_fwd));
        if (!cam[i].delta && !cam[i - 1].delta) sum += s == 0 && i == t - 1 ? ri * nee2 : ri;
    }
    ri = 1;
    const PathVertex& y0 = s == 1 && !own_y0 ? *sampled : light[0];
    for (int i = s - 1; i >= 0; --i) {
        const PathVertex& yi = i == 0 ? y0 : light[i];
        ri *= power_heuristic_ratio(remap(yi.pdf_rev), remap(yi.pdf_fwd));
        bool delta_before = i > 0 ? light[i - 1].delta : y0.is_delta_light();
        if (!yi.delta && !delta_before) sum += i == 1 ? ri * nee2 : ri;
    }
    if (s == 1) sum = nee2 > 0 ? sum / nee2 : Inf;
    for (int i = nt - 1; i >= 0; --i) {
        saved[std::size_t(i)].v->pdf_rev = saved[std::size_t(i)].pdf_rev;
        saved[std::size_t(i)].v->delta = saved[std::size_t(i)].delta;
    }
    return 1.0 / (1.0 + sum);
}

int BidirectionalPaths::strategy_weights(const Scene& scene, const PathVertex* light, const PathVertex* cam, int s,
                                         int t, double* w, StrategyDensities densities) const {
    const int k = s + t - 1;
    if (s == 1 || t < 2 || k < 1 || k + 1 > MaxVertices) return 0;
    if (!joinable(light, cam, s, t)) return 0;
    const Sensor& sensor = *scene.sensor();
    // The densities strategy (s, t) stores for the path: its subpaths as traced, the connection's vertices as
    // connect() sets them. x_i in light order; fwd: density of x_i from the light side, rev: from the camera side.
    std::array<PathVertex, MaxVertices> x, sub_light, sub_cam;
    std::array<double, MaxVertices> fwd, rev;
    std::copy(light, light + s, sub_light.begin());
    std::copy(cam, cam + t, sub_cam.begin());
    connection_densities(scene, sensor, sub_light.data(), sub_cam.data(), s, t);
    for (int i = 0; i <= k; ++i) {
        const bool from_light = i < s;
        const PathVertex& v = from_light ? sub_light[std::size_t(i)] : sub_cam[std::size_t(k - i)];
        x[std::size_t(i)] = v;
        fwd[std::size_t(i)] = from_light ? v.pdf_fwd : v.pdf_rev;
        rev[std::size_t(i)] = from_light ? v.pdf_rev : v.pdf_fwd;
    }
    // x_0 as a light subpath's origin holds: an emitter vertex, the emitter of an escaped camera ray being the
    // environment's.
    if (x[0].type == PathVertexType::Surface) x[0].type = PathVertexType::Light;
    if (x[0].is_infinite() && !x[0].emitter)
        for (const Emitter* e : scene.environment_emitters())
            if (!(e->flags() & EmitterFlags::Delta)) {
                x[0].emitter = e;  // the sky the camera ray escaped to (a directional light cannot be seen)
                break;
            }
    if (!x[0].emitter) return 0;
    if (densities == StrategyDensities::FromPositions) {
        // The same densities recomputed from the vertices' positions alone, by the functions the connections use.
        fwd[0] = pdf_light_origin(scene, x[0], x[1]);
        fwd[1] = pdf_light(scene, x[0], x[1]);
        for (int i = 2; i <= k; ++i)
            fwd[std::size_t(i)] = pdf(scene, sensor, x[std::size_t(i - 1)], &x[std::size_t(i - 2)], x[std::size_t(i)]);
        rev[std::size_t(k)] = 0;
        rev[std::size_t(k - 1)] = pdf(scene, sensor, x[std::size_t(k)], nullptr, x[std::size_t(k - 1)]);
        for (int i = k - 2; i >= 0; --i)
            rev[std::size_t(i)] = pdf(scene, sensor, x[std::size_t(i + 1)], &x[std::size_t(i + 2)], x[std::size_t(i)]);
    }

    // Every strategy (s', t'), each from these densities handed over to its own subpaths (a vertex that changes
    // subpath swaps its forward and reverse densities), then weighted by mis_weight() as connect() does.
    for (int sp = 0; sp <= k; ++sp) {
        const int tp = k + 1 - sp;
        for (int i = 0; i < sp; ++i) {
            sub_light[std::size_t(i)] = x[std::size_t(i)];
            sub_light[std::size_t(i)].pdf_fwd = fwd[std::size_t(i)];
            sub_light[std::size_t(i)].pdf_rev = rev[std::size_t(i)];
        }
        for (int j = 0; j < tp; ++j) {
            sub_cam[std::size_t(j)] = x[std::size_t(k - j)];
            sub_cam[std::size_t(j)].pdf_fwd = rev[std::size_t(k - j)];
            sub_cam[std::size_t(j)].pdf_rev = fwd[std::size_t(k - j)];
        }
        w[sp] = 0;
        if (sp == 1 && tp == 1 && !m_light_image) continue;  // bdpt without the light image never samples (1, 1)
        if (!joinable(sub_light.data(), sub_cam.data(), sp, tp)) continue;
        PathVertex sampled;
        if (sp == 1 && tp != 1) {
            const PathVertex& pt = sub_cam[std::size_t(tp - 1)];
            const Vec3d p = x[0].is_infinite() ? pt.p + glm::normalize(x[0].p - pt.p) : x[0].p;
            sampled = light_endpoint(scene, x[0].emitter, p, x[0].ng, pt);
        } else if (tp == 1) {
            sampled = sub_cam[0];
        }
        w[sp] = mis_weight(scene, sensor, sub_light.data(), sub_cam.data(), &sampled, sp, tp);
    }
    return k + 1;
}

}  // namespace kelvin
