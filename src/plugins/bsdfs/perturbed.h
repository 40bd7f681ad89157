#pragma once
// The common part of `normalmap` and `bumpmap` (Mitsuba 3.7's semantics): a nested BSDF evaluated in a perturbed
// shading frame. A subclass gives the perturbed normal in the local shading frame (unnormalised); this class
//  - optionally keeps that normal on the incident direction's side (`flip_invalid_normals`): when wi and the
//    perturbed normal disagree, its tangential part is mirrored, n = (-n.x, -n.y, n.z) (Schüssler et al. 2017,
//    "Microfacet-based normal mapping for robust Monte Carlo path tracing", take the flipped facet);
//  - builds the frame (n, s, t) with s the Gram-Schmidt of the local s axis against n and t = n x s;
//  - carries wi and wo into that frame; a wo on different sides of the two frames gives zero;
//  - optionally multiplies the value by the microfacet shadowing term of Conty Estevez, Lecocq and Stein 2019
//    (bump_shadow_terminator in render/microfacet.h; `use_shadowing_function`). The pdf is the nested BSDF's, so the
//    sampling weight carries G too and eval / pdf stays equal to the weight.
// Both options default to true, as in Mitsuba 3.7; false for both gives Mitsuba 3.6 and earlier.
#include <kelvin/core/properties.h>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/microfacet.h>

#include <fmt/format.h>

#include <cmath>
#include <memory>

namespace kelvin {

class PerturbedBsdf : public Bsdf {
public:
    uint32_t flags() const override { return m_nested->flags(); }

    std::optional<BsdfSample> sample(const BsdfContext& ctx, const SurfaceInteraction& si, double u1,
                                     const Vec2d& u2) const override {
        SurfaceInteraction p;
        const Frame local = perturb(si, p);
        auto bs = m_nested->sample(ctx, p, u1, u2);
        if (!bs) return bs;
        const Vec3d wo = local.to_world(bs->wo);
        if (!(bs->wo.z * wo.z > 0)) return std::nullopt;
        bs->wo = wo;
        if (m_shadowing) bs->weight *= bump_shadow_terminator(local.n, wo);
        return bs;
    }
    Color3 eval(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        SurfaceInteraction p;
        const Frame local = perturb(si, p);
        const Vec3d pwo = local.to_local(wo);
        if (!(wo.z * pwo.z > 0)) return Color3(0.0);
        const Color3 f = m_nested->eval(ctx, p, pwo);
        return m_shadowing ? f * bump_shadow_terminator(local.n, wo) : f;
    }
    double pdf(const BsdfContext& ctx, const SurfaceInteraction& si, const Vec3d& wo) const override {
        SurfaceInteraction p;
        const Frame local = perturb(si, p);
        const Vec3d pwo = local.to_local(wo);
        if (!(wo.z * pwo.z > 0)) return 0.0;
        return m_nested->pdf(ctx, p, pwo);
    }
    Color3 albedo(const SurfaceInteraction& si) const override { return m_nested->albedo(si); }

protected:
    PerturbedBsdf(const Properties& props, const char* name)
        : m_flip(props.get_bool("flip_invalid_normals")), m_shadowing(props.get_bool("use_shadowing_function")) {
        const std::vector<ObjectPtr> nested = props.get_objects("bsdf");
        if (nested.size() != 1)
            props.error("bsdf", fmt::format("{} needs exactly one nested <bsdf>, got {}", name, nested.size()));
        m_nested = std::dynamic_pointer_cast<Bsdf>(nested.front());
        if (!m_nested) props.error("bsdf", "the nested object is not a BSDF");
    }

    /// The perturbed normal in the local shading frame of `si`, not necessarily of unit length.
    virtual Vec3d perturbation(const SurfaceInteraction& si) const = 0;

private:
    /// Fills `p` (what the nested BSDF sees: the perturbed world frame and wi in it) and returns the perturbed
    /// frame in `si`'s local coordinates.
    Frame perturb(const SurfaceInteraction& si, SurfaceInteraction& p) const {
        Vec3d n = perturbation(si);
        if (m_flip && Frame::cos_theta(si.wi) * glm::dot(si.wi, n) <= 0) n = Vec3d(-n.x, -n.y, n.z);
        const double ln = glm::length(n);
        n = ln > 0 && std::isfinite(ln) ? n / ln : Vec3d(0, 0, 1);
        Frame local;
        local.n = n;
        const Vec3d s = Vec3d(1, 0, 0) - n * n.x;
        const double ls = glm::length(s);
        local.s = ls > 0 && std::isfinite(ls) ? s / ls : Vec3d(0, 1, 0);
        local.t = glm::cross(local.n, local.s);
        p = si;
        p.frame.n = si.to_world(local.n);
        p.frame.s = si.to_world(local.s);
        p.frame.t = si.to_world(local.t);
        p.ns = p.frame.n;
        p.wi = local.to_local(si.wi);
        return local;
    }

    bool m_flip, m_shadowing;
    std::shared_ptr<Bsdf> m_nested;
};

/// The parameters every perturbed BSDF declares besides its own.
#define KELVIN_PERTURBED_BSDF_PARAMS                                                                           \
    kelvin::param::objects("bsdf", "the nested BSDF (exactly one)"),                                           \
        kelvin::param::boolean("flip_invalid_normals", true,                                                   \
                               "mirror a perturbed normal that faces away from wi (Mitsuba 3.7; false: 3.6)"), \
        kelvin::param::boolean("use_shadowing_function", true,                                                 \
                               "microfacet shadowing of the perturbed surface (Conty Estevez et al. 2019)")

}  // namespace kelvin
