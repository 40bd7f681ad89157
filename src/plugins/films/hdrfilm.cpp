// hdrfilm: the image the sensor records (Mitsuba's `hdrfilm`). The output format is chosen by the output
// file's extension (kelvin -o out.png writes a PNG; .exr keeps full float precision and extra channels).
//
// | parameter | type    | default  | meaning                              |
// |-----------|---------|----------|--------------------------------------|
// | width     | integer | 768      | width in pixels                      |
// | height    | integer | 576      | height in pixels                     |
// | rfilter   | rfilter | gaussian | reconstruction filter (Mitsuba's default: gaussian, stddev 0.5) |
//
//     <film type="hdrfilm"><integer name="width" value="640"/><integer name="height" value="480"/></film>
#include <kelvin/core/registry.h>
#include <kelvin/render/film.h>

namespace kelvin {
namespace {

class HdrFilm final : public Film {
public:
    explicit HdrFilm(const Properties& props)
        : m_width(int(props.get_int("width", 1, 1 << 15))), m_height(int(props.get_int("height", 1, 1 << 15))) {
        m_filter = object_or_default<ReconstructionFilter>(props, "rfilter", "rfilter", "gaussian");
    }
    int width() const override { return m_width; }
    int height() const override { return m_height; }
    const ReconstructionFilter& filter() const override { return *m_filter; }

private:
    int m_width, m_height;
    std::shared_ptr<ReconstructionFilter> m_filter;
};

}  // namespace
}  // namespace kelvin

KELVIN_PLUGIN(kelvin::HdrFilm, "film", "hdrfilm", "High dynamic range film; format chosen by the output extension.",
              kelvin::param::integer("width", 768, "width in pixels"),
              kelvin::param::integer("height", 576, "height in pixels"),
              kelvin::param::object("rfilter", "rfilter", "reconstruction filter (default: gaussian)"));
