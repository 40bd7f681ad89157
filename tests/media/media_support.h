#pragma once
// Media-test support: plugin construction from C++, a sampler, and small OpenVDB files written into a TempDir.
#include "common/support.h"
#include "render/render_support.h"

#include <kelvin/core/registry.h>
#include <kelvin/render/medium.h>

#include <openvdb/openvdb.h>

#include <functional>
#include <memory>

namespace ktest {

template <typename T>
std::shared_ptr<T> make(kelvin::Properties props) {
    auto o = std::dynamic_pointer_cast<T>(kelvin::Registry::instance().create(props));
    if (!o) throw std::runtime_error("wrong plugin class");
    return o;
}

inline std::unique_ptr<kelvin::Sampler> make_sampler() {
    auto s = make<kelvin::Sampler>(kelvin::Properties("sampler", "independent"));
    return s->clone();
}

/// Write a float grid named `name` of n^3 voxels (index (0,0,0) .. (n-1)^3, voxel size h, origin at index 0)
/// with values f(i, j, k) to `path`; `extra` grids (a vec3s grid "velocity") may be added.
inline void write_vdb(const std::filesystem::path& path, const std::string& name, int n, double h,
                      const std::function<float(int, int, int)>& f, bool add_vector_grid = false) {
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName(name);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(h));
    auto acc = grid->getAccessor();
    for (int k = 0; k < n; ++k)
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) acc.setValueOn(openvdb::Coord(i, j, k), f(i, j, k));
    openvdb::GridPtrVec grids{grid};
    if (add_vector_grid) {
        auto v = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
        v->setName("velocity");
        v->setTransform(openvdb::math::Transform::createLinearTransform(h));
        auto va = v->getAccessor();
        for (int k = 0; k < 4; ++k)
            for (int j = 0; j < 4; ++j)
                for (int i = 0; i < 4; ++i) va.setValueOn(openvdb::Coord(i, j, k), openvdb::Vec3s(1, 0, 0));
        grids.push_back(v);
    }
    openvdb::io::File file(path.string());
    file.write(grids);
    file.close();
}

inline std::shared_ptr<kelvin::Medium> vdb_medium(const std::filesystem::path& path, const std::string& grid,
                                                  double scale, double albedo = 0.0, int block = 8) {
    kelvin::Properties vp("volume", "gridvolume");
    vp.set_string("filename", path.string());
    vp.set_string("grid", grid);
    kelvin::Properties mp("medium", "heterogeneous");
    mp.set_object("sigma_t", make<kelvin::Volume>(vp));
    mp.set_color("albedo", kelvin::Color3(albedo));
    mp.set_float("scale", scale);
    mp.set_int("majorant_block", block);
    return make<kelvin::Medium>(mp);
}

}  // namespace ktest
