// moment: Mitsuba 3's `moment` wrapper. Renders the nested sampling integrator unchanged (R, G, B are
// bit-identical to the nested integrator alone) and adds the per-pixel second moment of its estimates as extra
// channels m2.R, m2.G, m2.B: the filtered mean of the squared samples, so that m2 - mean^2 estimates the
// variance of one sample (Mitsuba's render tests read it to compute the variance of their references).
//
// Mitsuba allows several nested integrators; Kelvin takes exactly one (another is refused with one line).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="moment">
//         <integrator type="path"><integer name="max_depth" value="8"/></integrator>
//     </integrator>
#include <kelvin/core/registry.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

class MomentIntegrator final : public SamplingIntegrator {
public:
    explicit MomentIntegrator(const Properties& props) {
        const auto nested = props.get_objects("integrator");
        if (nested.empty()) props.error("integrator", "moment needs a nested <integrator>");
        if (nested.size() > 1)
            props.error("integrator",
                        fmt::format("moment takes one nested integrator in Kelvin (got {})", nested.size()));
        m_nested = std::dynamic_pointer_cast<SamplingIntegrator>(nested.front());
        if (!m_nested)
            props.error("integrator", fmt::format("the nested <integrator type=\"{}\"> has its own render loop; "
                                                  "moment wraps a sampling integrator (path, direct, ao, ...)",
                                                  nested.front()->plugin_name()));
        if (m_nested->splats())
            props.error("integrator", fmt::format("the nested <integrator type=\"{}\"> splats to other pixels; "
                                                  "its per-pixel second moment is not defined",
                                                  nested.front()->plugin_name()));
        if (!m_nested->extra_channels().empty())
            props.error("integrator", fmt::format("the nested <integrator type=\"{}\"> writes extra channels itself",
                                                  nested.front()->plugin_name()));
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& ray, SampleCounters& c) const override {
        Color3 v = m_nested->sample(scene, sampler, ray, c);
        // The pixel loop records the same value (zeroed when invalid); sample_extra, called next on this
        // thread for the same ray, squares it.
        Color3 recorded = v;
        sanitize(recorded);
        last_value() = recorded;
        return v;
    }
    int sample_streams() const override { return m_nested->sample_streams(); }
    void validate(const Scene& scene) const override { m_nested->validate(scene); }
    std::vector<std::string> extra_channels() const override { return {"m2.R", "m2.G", "m2.B"}; }
    void sample_extra(const Scene&, const Ray&, double* out, SampleCounters&) const override {
        const Color3 v = last_value();
        out[0] = v.r * v.r;
        out[1] = v.g * v.g;
        out[2] = v.b * v.b;
    }

private:
    static Color3& last_value() {
        thread_local Color3 value(0.0);
        return value;
    }
    std::shared_ptr<SamplingIntegrator> m_nested;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::MomentIntegrator, "integrator", "moment",
              "Mitsuba's moment wrapper: the nested integrator's image plus its second moment (m2.R, m2.G, m2.B).",
              kelvin::param::objects("integrator", "the nested sampling integrator (exactly one)"));
