// depth: an out-of-tree example integrator. It returns, as grey, the distance from the camera to the first
// surface hit along each camera ray, measured along the normalised ray direction and multiplied by `scale`;
// rays that hit nothing score 0. Averaged over the pixel's samples this is the pixel's mean depth, a useful
// check of a sensor's geometry and a template for writing one's own integrator.
//
// It is built outside Kelvin's source tree (see README.md next to this file) and loaded at run time with
// `--plugin-path`, KELVIN_PLUGIN_PATH or <plugin path="..."/>; the registration line at the end is the same
// one in-tree plugins use.
//
//     <integrator type="depth"><float name="scale" value="0.25"/></integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/scene.h>

namespace depth_example {
namespace {

using namespace kelvin;

class DepthIntegrator final : public SamplingIntegrator {
public:
    explicit DepthIntegrator(const Properties& props) : m_scale(props.get_float("scale", 0.0, Inf)) {
        if (!(m_scale > 0)) props.error("scale", "must be positive");
    }

    Color3 sample(const Scene& scene, Sampler&, const Ray& ray, SampleCounters& c) const override {
        ++c.rays;
        auto hit = scene.intersect(ray);
        if (!hit) return Color3(0.0);
        // Ray::t is measured in units of |d|; the depth is the Euclidean distance along the ray.
        return Color3(m_scale * hit->t * glm::length(ray.d));
    }

private:
    double m_scale;
};

}  // namespace
}  // namespace depth_example

KELVIN_PLUGIN(depth_example::DepthIntegrator, "integrator", "depth",
              "Distance to the first hit along the camera ray, as grey (0 on a miss). Out-of-tree example.",
              kelvin::param::real("scale", 1.0, "multiplies the depth (must be positive)"));
