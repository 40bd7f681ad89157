// null: an index-matched boundary (Mitsuba 3's `null`): light passes straight through, wo = -wi, with weight 1.
// It marks where a medium begins (a shape with `interior`/`exterior` media and no surface of its own). volpath
// crosses it without counting a bounce; integrators without media see a delta transmission (flags Null |
// DeltaTransmission), so `path` renders the shape as invisible too. No parameters.
//
//     <shape type="obj"><string name="filename" value="box.obj"/><bsdf type="null"/>
//         <ref name="interior" id="smoke"/></shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/bsdf.h>

namespace kelvin {
namespace {

class NullBsdf final : public Bsdf {
public:
    explicit NullBsdf(const Properties&) {}
    uint32_t flags() const override { return BsdfFlags::Null | BsdfFlags::DeltaTransmission; }
    std::optional<BsdfSample> sample(const BsdfContext&, const SurfaceInteraction& si, double,
                                     const Vec2d&) const override {
        BsdfSample bs;
        bs.wo = -si.wi;
        bs.weight = Color3(1.0);
        bs.pdf = 1;
        bs.sampled = BsdfFlags::Null | BsdfFlags::DeltaTransmission;
        bs.eta = 1;
        return bs;
    }
    Color3 eval(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return Color3(0.0); }
    double pdf(const BsdfContext&, const SurfaceInteraction&, const Vec3d&) const override { return 0.0; }
    Color3 eval_null_transmission(const SurfaceInteraction&) const override { return Color3(1.0); }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::NullBsdf, "bsdf", "null", "Index-matched boundary: light passes straight through.");
