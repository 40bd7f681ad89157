// grid: the uniform single-grid cache of thesis Section 5.3.3. It stores the vorticity of the previous step
// at the cell centres; the semi-Lagrangian lookups and the Biot–Savart samples read it through the chosen
// interpolation (nearest: piecewise constant; bilinear: tents between cell centres).
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <cache type="grid"><integer name="resolution" value="256"/></cache>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/fields.h>

namespace kelvin::fluid {
namespace {

class GridCache final : public CacheSpec {
public:
    explicit GridCache(const Properties& props)
        : m_nx(int(props.get_int("resolution", 2, 16384))),
          m_ny(int(props.get_int("resolution_y"))),
          m_nz(int(props.get_int("resolution_z"))) {
        if (m_ny != 0 && (m_ny < 2 || m_ny > 16384))
            props.error("resolution_y", "must lie in [2, 16384], or be 0 for square cells");
        if (m_nz != 0 && (m_nz < 2 || m_nz > 16384))
            props.error("resolution_z", "must lie in [2, 16384], or be 0 for cubic cells");
        m_interp = props.get_choice("interpolation", {"nearest", "bilinear", "trilinear"}) == "nearest"
                       ? Interpolation::Nearest
                       : Interpolation::Bilinear;
    }
    int resolution_x() const override { return m_nx; }
    int resolution_y() const override { return m_ny; }
    int resolution_z() const override { return m_nz; }
    Interpolation interpolation() const override { return m_interp; }

private:
    int m_nx, m_ny, m_nz;
    Interpolation m_interp;
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(kelvin::fluid::GridCache, "cache", "grid",
              "Uniform grid cache of the previous step's vorticity at cell centres (Section 5.3.3).",
              kelvin::param::integer("resolution", 64, "cells along x"),
              kelvin::param::integer("resolution_y", 0,
                                     "cells along y; 0: square cells (sides within 64x of each other)"),
              kelvin::param::integer("resolution_z", 0,
                                     "cells along z (3D); 0: cubic cells (sides within 64x of each other)"),
              kelvin::param::string("interpolation", "bilinear",
                                    "'nearest', 'bilinear' or 'trilinear' (3D: the same tent basis)"));
