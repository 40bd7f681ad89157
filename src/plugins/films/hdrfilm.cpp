// hdrfilm: the image the sensor records (Mitsuba's `hdrfilm`). The output format is chosen by the output
// file's extension (kelvin -o out.png writes a PNG; .exr keeps full float precision and extra channels).
//
// Parameters (kelvin --list-plugins film hdrfilm): width and height in pixels (768 x 576); rfilter, the
// reconstruction filter (Mitsuba's default: gaussian, stddev 0.5); Mitsuba's output options pixel_format ("rgb" is
// what Kelvin writes; others are refused), component_format ("float16" or "float32": EXR is written as float32 either
// way; "uint32" is refused), file_format ("openexr"; other formats come from -o name.ext) and banner (accepted, never
// drawn); and reconstruction, how camera samples become pixels:
//   "splat" (default, as Mitsuba): a sample at a uniform position in its pixel is weighted by the filter into every
//   pixel within the filter's radius, and a pixel is the weighted average of the samples that reach it. With the
//   default Gaussian a pixel averages about 3 pixels' worth of samples (about 3x lower per-pixel variance), and
//   neighbouring pixels share samples.
//   "importance" (pbrt-v4's filter importance sampling): the sample's offset is drawn from the filter and it counts in
//   its own pixel only: independent pixels, with a box filter's per-pixel variance.
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
        m_reconstruction = props.get_choice("reconstruction", {"splat", "importance"}) == "importance"
                               ? Reconstruction::Importance
                               : Reconstruction::Splat;
    }
    int width() const override { return m_width; }
    int height() const override { return m_height; }
    const ReconstructionFilter& filter() const override { return *m_filter; }
    Reconstruction reconstruction() const override { return m_reconstruction; }

private:
    int m_width, m_height;
    Reconstruction m_reconstruction = Reconstruction::Splat;
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
              kelvin::param::boolean("banner", true, "accepted; Kelvin draws no banner"),
              kelvin::param::string("reconstruction", "splat",
                                    "splat: each sample weighted into every pixel of the filter's footprint "
                                    "(Mitsuba); importance: filter importance sampling, one pixel per sample "
                                    "(pbrt-v4)"));
