// shapegroup and instance: Mitsuba's instancing. A `shapegroup` (declared with an id, usually at the scene's root)
// holds shapes that are not rendered by themselves; each `instance` references one group and places it with
// `to_world`. The scene builds the group's geometry once, as its own Embree scene, and traces every instance as
// an Embree instance of it (so a thousand instances of a large mesh cost one mesh of memory).
//
// Refused, each in one line: area emitters in a group (Mitsuba does not instance emitters either), media on a
// grouped shape, groups or instances nested in a group, an instance without exactly one group, and a singular
// to_world.
//
// | plugin     | parameter | type      | meaning                                   |
// |------------|-----------|-----------|-------------------------------------------|
// | shapegroup | (shape)   | shape     | the shapes of the group (one or more)     |
// | instance   | (shape)   | shapegroup| the group, usually by <ref id="..."/>     |
// | instance   | to_world  | transform | where the group is placed                 |
//
//     <shape type="shapegroup" id="tree">
//         <shape type="ply"><string name="filename" value="tree.ply"/><bsdf type="diffuse"/></shape>
//     </shape>
//     <shape type="instance"><ref id="tree"/><transform name="to_world"><translate x="3"/></transform></shape>
#include <kelvin/core/registry.h>
#include <kelvin/render/shape.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin {
namespace {

class ShapeGroupPlugin final : public ShapeGroup {
public:
    explicit ShapeGroupPlugin(const Properties& props) : ShapeGroup(collect(props)) {}

private:
    static std::vector<std::shared_ptr<Shape>> collect(const Properties& props) {
        std::vector<std::shared_ptr<Shape>> shapes;
        for (const ObjectPtr& o : props.get_objects("shape")) {
            if (std::dynamic_pointer_cast<ShapeGroup>(o) || std::dynamic_pointer_cast<ShapeInstance>(o))
                props.error("shape", fmt::format("a shapegroup cannot contain a {} (nested instancing is not "
                                                 "supported)",
                                                 o->plugin_name()));
            auto shape = std::dynamic_pointer_cast<Shape>(o);
            if (!shape) props.error("shape", "the nested object is not a shape");
            if (shape->emitter())
                props.error("shape", fmt::format("{} in a shapegroup has an area emitter: emitters cannot be "
                                                 "instanced (declare that shape outside the group)",
                                                 shape->to_string()));
            if (shape->is_medium_transition())
                props.error("shape", fmt::format("{} in a shapegroup has an interior or exterior medium: media "
                                                 "cannot be instanced (declare that shape outside the group)",
                                                 shape->to_string()));
            shapes.push_back(std::move(shape));
        }
        if (shapes.empty()) props.error("shape", "a shapegroup needs at least one nested <shape>");
        return shapes;
    }
};

class InstancePlugin final : public ShapeInstance {
public:
    explicit InstancePlugin(const Properties& props) : ShapeInstance(group(props), transform(props)) {}

private:
    static std::shared_ptr<const ShapeGroup> group(const Properties& props) {
        const std::vector<ObjectPtr> nested = props.get_objects("shape");
        if (nested.size() != 1)
            props.error("shape", fmt::format("an instance needs exactly one shapegroup (<ref id=\"...\"/>), got {} "
                                             "nested shape(s)",
                                             nested.size()));
        auto g = std::dynamic_pointer_cast<const ShapeGroup>(nested.front());
        if (!g)
            props.error("shape",
                        fmt::format("an instance references a shapegroup, not a {}", nested.front()->plugin_name()));
        return g;
    }
    static Transform transform(const Properties& props) {
        const Transform t = props.get_transform("to_world");
        const double det = glm::determinant(Mat3d(t.matrix));
        if (!(std::abs(det) > 0) || !std::isfinite(det))
            props.error("to_world", "is singular or not finite: the instance would collapse");
        return t;
    }
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::ShapeGroupPlugin, "shape", "shapegroup",
              "Shapes declared once and placed by instances (Mitsuba's shapegroup); not rendered by itself.",
              kelvin::param::objects("shape", "the shapes of the group"));
KELVIN_PLUGIN(kelvin::InstancePlugin, "shape", "instance",
              "A shapegroup placed by to_world (Mitsuba's instance; an Embree instance of the group's geometry).",
              kelvin::param::objects("shape", "the shapegroup, by <ref id=\"...\"/>"),
              kelvin::param::transform("to_world", "object-to-world transform of the group"));
