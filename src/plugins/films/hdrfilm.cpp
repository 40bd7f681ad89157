// hdrfilm: the image the sensor records (Mitsuba's `hdrfilm`). The output format is chosen by the output
// file's extension (kelvin -o out.png writes a PNG; .exr keeps full float precision and extra channels).
//
// | parameter | type    | default  | meaning                              |
// |-----------|---------|----------|--------------------------------------|
// | width     | integer | 768      | width in pixels                      |
// | height    | integer | 576      | height in pixels                     |
// | rfilter   | rfilter | gaussian | reconstruction filter (Mitsuba's default: gaussian, stddev 0.5) |
// | pixel_format | string | "rgb"   | Mitsuba's pixel format: "rgb" is what Kelvin writes; "rgba", "luminance", ... are
// refused | | component_format | string | "float16" | "float16" or "float32": EXR output is written as float32 either
// way (values are not rounded to half precision); "uint32" is refused | | file_format | string | "openexr" | "openexr"
// (Kelvin's default output); other formats are chosen with `-o name.ext`, so "rgbe"/"pfm" are refused here | | banner
// | boolean | true     | accepted: Kelvin never draws a banner (Mitsuba 3's hdrfilm ignores it too) |
//
//     <film type="hdrfilm"><integer name="width" value="640"/><integer name="height" value="480"/></film>
#include <kelvin/core/registry.h>
#include <kelvin/render/film.h>

#include <fmt/format.h>

namespace kelvin {
namespace {

class HdrFilm final : public Film {
public:
    explicit HdrFilm(const Properties& props)
        : m_width(int(props.get_int("width", 1, 1 << 15))), m_height(int(props.get_int("height", 1, 1 << 15))) {
        m_filter = object_or_default<ReconstructionFilter>(props, "rfilter", "rfilter", "gaussian");
        // Mitsuba's output options: honoured where Kelvin writes the same thing, otherwise refused in one line.
        const std::string pf = props.get_choice(
            "pixel_format", {"rgb", "rgba", "luminance", "luminance_alpha", "xyz", "xyza", "multichannel"});
        if (pf != "rgb")
            props.error("pixel_format", fmt::format("'{}' is not supported: Kelvin's hdrfilm writes rgb", pf));
        const std::string cf = props.get_choice("component_format", {"float16", "float32", "uint32"});
        if (cf == "uint32")
            props.error("component_format", "'uint32' is not supported: Kelvin writes float32 EXR channels");
        const std::string ff = props.get_choice("file_format", {"openexr", "exr", "rgbe", "pfm"});
        if (ff != "openexr" && ff != "exr")
            props.error("file_format", fmt::format("'{}' is not supported here: Kelvin writes OpenEXR by default and "
                                                   "picks other formats from the output name (-o image.{})",
                                                   ff, ff == "rgbe" ? "hdr" : "pfm"));
        (void)props.get_bool("banner");
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
              kelvin::param::object("rfilter", "rfilter", "reconstruction filter (default: gaussian)"),
              kelvin::param::string("pixel_format", "rgb", "Mitsuba's pixel format; only rgb is written"),
              kelvin::param::string("component_format", "float16", "float16 or float32 (written as float32)"),
              kelvin::param::string("file_format", "openexr", "openexr (other formats: -o name.hdr / .pfm)"),
              kelvin::param::boolean("banner", true, "accepted; Kelvin draws no banner"));
