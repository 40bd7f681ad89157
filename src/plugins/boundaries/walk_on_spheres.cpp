// walk_on_spheres: the free-slip velocity estimator of thesis Section 5.3.1, a drop-in replacement for
// biot_savart in <simulation type="mcfluid"> (same cache, same time stepping). The stream function solves
//
//     Laplacian(Psi) = omega   in the fluid,        Psi = Psi_b   on every boundary          (Eqs. 5.9-5.11)
//
// and the velocity is v = -curl Psi = (-dPsi/dy, dPsi/dx) (Eq. 5.8), from the gradient Walk-on-Spheres estimator
// (Eqs. 3.78-3.79) with an antithetic first step (Fig. 5.5) and the volume term sampled from the vorticity
// cache; by default (control_variate, stratified; 2D and 3D) as the free-space Biot–Savart velocity of point-vortex
// samples of the cache plus the walks' harmonic correction, with stratified first-step directions
// (include/kelvin/fluid/boundary.h, docs/boundaries.md). Boundaries: the domain box as walls (unless periodic), with
// optional inflow through its left wall and outflow through its right (Fig. 5.6), and the nested <boundary> shapes,
// each with its isovalue, possibly moving rigidly (Eqs. 5.12-5.13). Cells inside solids hold zero vorticity and the
// solid's velocity; departure points that land inside a solid are moved to its surface. In 3D (dimension = 3
// simulations, 3D boundaries) the stream function is a vector potential with Psi constant on solids and the walls
// carrying the uniform stream of `inflow_speed` along +x (include/kelvin/fluid/boundary.h, WosVelocityField3). See
// docs/boundaries.md.
//
// Parameters: `kelvin --list-plugins KIND NAME`, or docs/reference.md (generated from the declarations below).
//
//     <velocity type="walk_on_spheres">
//         <integer name="samples" value="64"/>
//         <boundary type="disk"><point name="center" x="0" y="0"/><float name="radius" value="0.2"/></boundary>
//     </velocity>
#include <kelvin/core/logging.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/boundary.h>

#include <fmt/format.h>

#include <cmath>

namespace kelvin::fluid {
namespace {

class WalkOnSpheres final : public WosVelocity {
public:
    explicit WalkOnSpheres(const Properties& props) {
        WosVelocityOptions opt;
        opt.samples = int(props.get_int("samples", 1, 1 << 24));
        opt.wos.epsilon = props.get_float("epsilon", 0.0, 1e300);
        opt.wos.max_steps = int(props.get_int("max_steps", 1, 1 << 30));
        opt.wos.antithetic = props.get_bool("antithetic");
        opt.vorticity_importance = props.get_choice("importance", {"vorticity", "green"}) == "vorticity";
        opt.control_variate = props.get_bool("control_variate");
        opt.free_samples = int(props.get_int("free_samples", 1, MaxFreeSamples));
        opt.stratified = props.get_bool("stratified");
        opt.harmonic_cache = props.get_bool("harmonic_cache");
        opt.cache_walks = props.get_float("cache_walks", 0.01, 1e4);
        opt.cache_order = int(props.get_int("cache_order", 1, MaxCacheOrder));
        opt.cache_degree = int(props.get_int("cache_degree", 1, MaxCacheDegree));
        opt.walls = props.get_bool("walls");
        opt.wall_stream_value = props.get_float("wall_stream_value");
        opt.inflow_speed = props.get_float("inflow_speed");
        opt.inflow_min = props.get_float("inflow_min");
        opt.inflow_max = props.get_float("inflow_max");
        for (const char* n : {"wall_stream_value", "inflow_speed", "inflow_min", "inflow_max"})
            if (!std::isfinite(props.get_float(n))) props.error(n, "must be finite");
        if (opt.inflow_min > opt.inflow_max) props.error("inflow_max", "must be >= inflow_min");
        for (const ObjectPtr& o : props.get_objects("boundary")) {
            auto b = std::dynamic_pointer_cast<const BoundaryShape>(o);
            if (!b) props.error("boundary", "not a boundary shape");
            opt.shapes.push_back(b);  // the simulation checks the dimension (check_wos_options / 3)
        }
        // Section 6.2.4: with several disjoint boundaries the isovalues set the flux between them. Say so when
        // the scene left any obstacle's at the default (the thesis' choice: no net flow between boundaries).
        int obstacles = 0, defaulted = 0;
        bool outer = opt.walls;
        for (const auto& b : opt.shapes) {
            if (b->dimension() != 2) continue;  // 3D solids take constant vector potentials (boundary.h)
            if (b->role().fluid_inside) {
                outer = true;
                continue;
            }
            ++obstacles;
            if (!b->role().stream_value_given) ++defaulted;
        }
        if (defaulted > 0 && obstacles + (outer ? 1 : 0) >= 2)
            log_warn(
                "walk_on_spheres: {} obstacle(s) take the default stream_value 0 (the walls' value, or their mean with "
                "inflow): that fixes the flux between them and the walls (thesis Section 6.2.4; right for symmetric "
                "layouts). Give stream_value per boundary to choose it (docs/boundaries.md).",
                defaulted);
        if (!opt.wos.antithetic)
            log_warn("walk_on_spheres: antithetic = false: the gradient variance grows with |Psi| on the boundary");
        m_options = std::make_shared<const WosVelocityOptions>(std::move(opt));
    }
};

}  // namespace
}  // namespace kelvin::fluid

KELVIN_PLUGIN(
    kelvin::fluid::WalkOnSpheres, "velocity", "walk_on_spheres",
    "Free-slip velocity by Walk-on-Spheres on the stream function (Sec. 5.3.1; 3D: vector potential): walls, "
    "inflow/outflow, obstacles, moving solids (2D).",
    kelvin::param::integer("samples", 64,
                           "gradient samples per velocity query (2 walks each, antithetic; --samples overrides)"),
    kelvin::param::real("epsilon", 0.0, "shell width; 0: 1e-4 x the domain's smaller side"),
    kelvin::param::integer("max_steps", 4096, "spheres per walk before truncation (counted)"),
    kelvin::param::boolean("antithetic", true, "antithetic first step (Fig. 5.5)"),
    kelvin::param::string("importance", "vorticity",
                          "volume term: 'vorticity' (|omega| mixed with G) or 'green' (G only, the thesis)"),
    kelvin::param::boolean("control_variate", true,
                           "with vorticity (3D: not periodic): Biot-Savart velocity of point-vortex samples (periodic "
                           "ones on periodic domains) + walks for the harmonic correction only (false: walks with the "
                           "vorticity source)"),
    kelvin::param::integer("free_samples", 16,
                           "control variate: vorticity samples (point vortices) per gradient sample, 1-256"),
    kelvin::param::boolean("stratified", true,
                           "stratified first-step directions over a query's gradient samples (3D: with the control "
                           "variate only)"),
    kelvin::param::boolean("harmonic_cache", true,
                           "where the control variate applies: the walls' harmonic correction once per step on disks "
                           "(3D: balls) away "
                           "from the boundaries (their series read by every query inside), walks per query only "
                           "near them"),
    kelvin::param::real("cache_walks", 1.0, "harmonic_cache: walks per cell of a disk's (ball's) core"),
    kelvin::param::integer("cache_order", 12, "harmonic_cache, 2D: terms of each disk's Fourier series, 1-32"),
    kelvin::param::integer("cache_degree", 6, "harmonic_cache, 3D: degree of each ball's solid-harmonic series, 1-16"),
    kelvin::param::boolean("walls", true, "the domain box is a container (ignored when periodic)"),
    kelvin::param::real("wall_stream_value", 0.0,
                        "Psi on the walls (with inflow: the mean of the bottom and top walls)"),
    kelvin::param::real("inflow_speed", 0.0, "inflow speed through the left wall, outflow through the right"),
    kelvin::param::real("inflow_min", 0.0, "lower y of the inflow/outflow segments"),
    kelvin::param::real("inflow_max", 0.0, "upper y (equal to inflow_min: the whole wall)"),
    kelvin::param::objects("boundary", "solid boundaries (obstacles, containers)"));
