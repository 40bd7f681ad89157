// aov: arbitrary output variables, as Mitsuba 3's `aov` integrator. Wraps an optional nested sampling
// integrator, whose colour goes to channels R, G, B (black without one), and writes properties of the first
// camera hit as extra named channels, which the EXR output keeps by name.
//
// `aovs` lists `name:type` entries, comma-separated. Channel names: scalar types write `name`; 3-vectors
// write `name.X`, `name.Y`, `name.Z`; uv writes `name.U`, `name.V`; albedo writes `name.R`, `name.G`, `name.B`.
//
// | type        | channels | value at the first hit of the camera ray                                   |
// |-------------|----------|-----------------------------------------------------------------------------|
// | depth       | 1        | distance from the ray origin to the hit (t |d|)                            |
// | position    | 3 (XYZ)  | world-space hit point                                                       |
// | uv          | 2 (UV)   | texture coordinates                                                         |
// | geo_normal  | 3 (XYZ)  | geometric normal, as the shape orients it (not flipped towards the camera)  |
// | sh_normal   | 3 (XYZ)  | shading normal (interpolated vertex normal, else the geometric normal)      |
// | shape_index | 1        | index of the shape in the scene (declaration order, from 0)                 |
// | prim_index  | 1        | primitive (triangle, or sphere) index within the shape                      |
// | albedo      | 3 (RGB)  | diffuse reflectance of the BSDF (Bsdf::albedo; 0 without a diffuse part)    |
//
// Misses give 0 in every AOV channel. The pixel loop filters AOVs exactly like the colour (same camera
// samples, same reconstruction-filter weights, same normalisation), so pixels on an edge hold weighted
// means (a shape index of 0.5 between shapes 0 and 1), as in Mitsuba; use a box filter and 1 spp for hard
// edges. The AOV ray is traced apart from the nested integrator's (one more ray per sample, counted in
// render.rays) and draws no sampler numbers, so R, G, B are bit-identical to the nested integrator alone.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <integrator type="aov">
//         <string name="aovs" value="dd:depth,nn:sh_normal,pos:position"/>
//         <integrator type="path"><integer name="max_depth" value="8"/></integrator>
//     </integrator>
#include <kelvin/core/registry.h>
#include <kelvin/core/strings.h>
#include <kelvin/render/bsdf.h>
#include <kelvin/render/scene.h>

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <string_view>

namespace kelvin {
namespace {

enum class AovType { Depth, Position, Uv, GeoNormal, ShNormal, ShapeIndex, PrimIndex, Albedo };

struct AovTypeInfo {
    const char* name;
    AovType type;
    std::vector<const char*> suffixes;  ///< empty: one channel named as given
};

const std::array<AovTypeInfo, 8>& aov_types() {
    static const std::array<AovTypeInfo, 8> types = {{
        {"depth", AovType::Depth, {}},
        {"position", AovType::Position, {"X", "Y", "Z"}},
        {"uv", AovType::Uv, {"U", "V"}},
        {"geo_normal", AovType::GeoNormal, {"X", "Y", "Z"}},
        {"sh_normal", AovType::ShNormal, {"X", "Y", "Z"}},
        {"shape_index", AovType::ShapeIndex, {}},
        {"prim_index", AovType::PrimIndex, {}},
        {"albedo", AovType::Albedo, {"R", "G", "B"}},
    }};
    return types;
}

class AovIntegrator final : public SamplingIntegrator {
public:
    explicit AovIntegrator(const Properties& props) {
        if (ObjectPtr o = props.get_object("integrator")) {
            m_nested = std::dynamic_pointer_cast<SamplingIntegrator>(o);
            // Only a per-camera-ray estimator can share the pixel loop (and so the camera samples) with the AOVs.
            if (!m_nested)
                props.error("integrator", fmt::format("the nested <integrator type=\"{}\"> has its own render loop; "
                                                      "aov wraps a sampling integrator (path, bdpt, ao)",
                                                      o->plugin_name()));
            if (!m_nested->extra_channels().empty())
                props.error("integrator", fmt::format("the nested <integrator type=\"{}\"> writes extra channels "
                                                      "itself; list every AOV in one aov integrator",
                                                      o->plugin_name()));
        }
        parse(props);
    }

    Color3 sample(const Scene& scene, Sampler& sampler, const Ray& ray, SampleCounters& c) const override {
        return m_nested ? m_nested->sample(scene, sampler, ray, c) : Color3(0.0);
    }
    bool splats() const override { return m_nested && m_nested->splats(); }
    int sample_streams() const override { return m_nested ? m_nested->sample_streams() : 1; }
    void validate(const Scene& scene) const override {
        if (m_nested) m_nested->validate(scene);
    }
    std::vector<std::string> extra_channels() const override { return m_channels; }

    void sample_extra(const Scene& scene, const Ray& ray, double* out, SampleCounters& c) const override {
        ++c.rays;
        const auto hit = scene.intersect(ray);
        if (!hit) {
            std::fill(out, out + m_channels.size(), 0.0);
            return;
        }
        const SurfaceInteraction si = scene.interaction(ray, *hit);
        for (const AovType type : m_types) {
            switch (type) {
                case AovType::Depth:
                    *out++ = si.t * glm::length(ray.d);  // t is in units of |d|
                    break;
                case AovType::Position:
                    out = put(out, si.p);
                    break;
                case AovType::Uv:
                    *out++ = si.uv.x;
                    *out++ = si.uv.y;
                    break;
                case AovType::GeoNormal:
                    out = put(out, si.ng);
                    break;
                case AovType::ShNormal:
                    out = put(out, si.ns);
                    break;
                case AovType::ShapeIndex:
                    *out++ = double(si.shape_index);
                    break;
                case AovType::PrimIndex:
                    *out++ = double(si.prim);
                    break;
                case AovType::Albedo: {
                    const Bsdf* bsdf = si.shape ? si.shape->bsdf() : nullptr;
                    out = put(out, bsdf ? bsdf->albedo(si) : Color3(0.0));
                    break;
                }
            }
        }
    }

private:
    static double* put(double* out, const Vec3d& v) {
        out[0] = v.x;
        out[1] = v.y;
        out[2] = v.z;
        return out + 3;
    }

    void parse(const Properties& props) {
        const std::string list = props.get_string("aovs");
        std::vector<std::string> type_names;
        for (const auto& t : aov_types()) type_names.push_back(t.name);
        std::size_t start = 0;
        while (start <= list.size()) {
            const std::size_t comma = std::min(list.find(',', start), list.size());
            const std::string entry(trim(std::string_view(list).substr(start, comma - start)));
            start = comma + 1;
            if (entry.empty()) {
                if (list.find_first_not_of(" \t\r\n") == std::string::npos)
                    props.error("aovs", "lists no AOV (expected name:type entries, e.g. \"dd:depth\")");
                props.error("aovs", fmt::format("has an empty entry in \"{}\"", list));
            }
            const std::size_t colon = entry.find(':');
            if (colon == std::string::npos) props.error("aovs", fmt::format("entry \"{}\" is not name:type", entry));
            const std::string name(trim(std::string_view(entry).substr(0, colon)));
            const std::string type(trim(std::string_view(entry).substr(colon + 1)));
            if (name.empty()) props.error("aovs", fmt::format("entry \"{}\" has an empty channel name", entry));
            if (std::any_of(name.begin(), name.end(), [](char ch) { return std::isspace((unsigned char)ch); }))
                props.error("aovs", fmt::format("channel name \"{}\" contains whitespace", name));
            const auto* info = std::find_if(aov_types().begin(), aov_types().end(),
                                            [&](const AovTypeInfo& t) { return type == t.name; });
            if (info == aov_types().end())
                props.error("aovs", fmt::format("unknown AOV type \"{}\" in \"{}\"{}; known: {}", type, entry,
                                                did_you_mean(type, type_names), fmt::join(type_names, ", ")));
            m_types.push_back(info->type);
            if (info->suffixes.empty()) add_channel(props, name);
            for (const char* s : info->suffixes) add_channel(props, name + "." + s);
        }
        if (m_channels.size() > std::size_t(MaxExtraChannels))
            props.error("aovs", fmt::format("gives {} channels; at most {} are supported", m_channels.size(),
                                            int(MaxExtraChannels)));
    }

    void add_channel(const Properties& props, const std::string& name) {
        if (name == "R" || name == "G" || name == "B")
            props.error("aovs", fmt::format("channel \"{}\" would replace the colour channel of that name", name));
        if (std::find(m_channels.begin(), m_channels.end(), name) != m_channels.end())
            props.error("aovs", fmt::format("channel \"{}\" is given twice", name));
        m_channels.push_back(name);
    }

    std::shared_ptr<SamplingIntegrator> m_nested;
    std::vector<AovType> m_types;         ///< in `aovs` order
    std::vector<std::string> m_channels;  ///< their channel names, in the same order
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::AovIntegrator, "integrator", "aov",
              "Arbitrary output variables (depth, position, uv, normals, indices, albedo) as extra EXR channels, "
              "around an optional nested integrator for R, G, B.",
              kelvin::param::required(kelvin::PropType::String, "aovs",
                                      "name:type list; types depth, position, uv, geo_normal, sh_normal, "
                                      "shape_index, prim_index, albedo"),
              kelvin::param::object("integrator", "integrator",
                                    "nested sampling integrator for R, G, B (none: black)"));
