// Kelvin's OpenVDB module (libkelvin_vdb.so): reading level sets and volumes from .vdb files and writing grids given
// as plain arrays (the 3D simulations' frames; include/kelvin/core/vdb.h). libkelvin loads it with dlopen on the first
// .vdb file (src/core/modules.h): OpenVDB's ~70,000 symbol relocations used to be most of the dynamic loader's work at
// every kelvin start-up.
#include "core/vdb_io.h"

#include <kelvin/core/files.h>

#include <fmt/format.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

#include <mutex>

namespace kelvin::detail {
namespace {

void initialize() {
    static std::once_flag once;
    std::call_once(once, [] { openvdb::initialize(); });
}

Vec3d to_vec(const openvdb::Vec3d& v) { return {v.x(), v.y(), v.z()}; }

class FloatGrid final : public VdbFloatGrid {
public:
    explicit FloatGrid(openvdb::FloatGrid::Ptr grid) : m_grid(std::move(grid)) {}
    double sample(const Vec3d& p, bool* in_leaf) const override {
        const openvdb::Vec3d ijk = m_grid->worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
        if (in_leaf) *in_leaf = m_grid->constTree().probeConstLeaf(openvdb::Coord::floor(ijk)) != nullptr;
        return double(openvdb::tools::BoxSampler::sample(m_grid->constTree(), ijk));
    }

private:
    openvdb::FloatGrid::Ptr m_grid;
};

std::unique_ptr<VdbFloatGrid> read_float_grid(const std::filesystem::path& path, const std::string& want) {
    initialize();
    const std::string file = path.string();
    openvdb::GridBase::Ptr base;
    try {
        openvdb::io::File f(file);
        f.open();
        if (want.empty()) {
            for (auto it = f.beginName(); it != f.endName(); ++it) {
                openvdb::GridBase::Ptr g = f.readGrid(it.gridName());
                if (openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
                    base = g;
                    break;
                }
            }
            if (!base) throw VdbInputError("filename", fmt::format("'{}' has no float grid", file));
        } else {
            if (!f.hasGrid(want)) throw VdbInputError("grid", fmt::format("'{}' has no grid named '{}'", file, want));
            base = f.readGrid(want);
        }
        f.close();
    } catch (const openvdb::Exception& e) {
        throw VdbInputError("filename", fmt::format("cannot read OpenVDB file '{}': {}", file, e.what()));
    }
    auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
    if (!grid) throw VdbInputError("grid", fmt::format("grid '{}' in '{}' is not a float grid", base->getName(), file));
    if (!grid->transform().isLinear())
        throw VdbInputError("filename", fmt::format("'{}': only linear (voxel) transforms are supported", file));
    const openvdb::CoordBBox bb = grid->evalActiveVoxelBoundingBox();
    if (bb.empty())
        throw VdbInputError("filename", fmt::format("grid '{}' in '{}' has no active voxels", grid->getName(), file));
    auto out = std::make_unique<FloatGrid>(grid);
    out->grid_name = grid->getName();
    out->voxel = grid->voxelSize()[0];
    out->background = std::abs(double(grid->background()));
    const Vec3d a = to_vec(grid->indexToWorld(bb.min().asVec3d() - 1.0));
    const Vec3d b = to_vec(grid->indexToWorld(bb.max().asVec3d() + 1.0));
    out->lo = glm::min(a, b);
    out->hi = glm::max(a, b);
    for (auto leaf = grid->constTree().cbeginLeaf(); leaf; ++leaf) {
        const openvdb::CoordBBox nb = leaf->getNodeBoundingBox();
        out->leaf_boxes.emplace_back(to_vec(grid->indexToWorld(nb.min().asVec3d() - 0.5)),
                                     to_vec(grid->indexToWorld(nb.max().asVec3d() + 0.5)));
    }
    return out;
}

template <typename GridT, int C>
void copy_dense(const GridT& g, const openvdb::CoordBBox& bb, VdbDense& d) {
    auto acc = g.getConstAccessor();
    d.data.resize(std::size_t(d.res[0]) * std::size_t(d.res[1]) * std::size_t(d.res[2]) * C);
    std::size_t k = 0;
    for (int z = 0; z < d.res[2]; ++z)
        for (int y = 0; y < d.res[1]; ++y)
            for (int x = 0; x < d.res[0]; ++x) {
                const auto v = acc.getValue(bb.min().offsetBy(x, y, z));
                if constexpr (C == 1) {
                    d.data[k++] = float(v);
                } else {
                    d.data[k++] = float(v[0]);
                    d.data[k++] = float(v[1]);
                    d.data[k++] = float(v[2]);
                }
            }
}

VdbDense read_dense(const std::filesystem::path& path, const std::string& name, double max_voxels) {
    initialize();
    const std::string file = path.string();
    openvdb::GridBase::Ptr base;
    try {
        openvdb::io::File f(file);
        f.open();
        std::vector<std::string> names;
        for (auto it = f.beginName(); it != f.endName(); ++it) names.push_back(it.gridName());
        if (names.empty()) throw VdbInputError("filename", fmt::format("'{}' has no grids", file));
        const std::string chosen = name.empty() ? names.front() : name;
        if (std::find(names.begin(), names.end(), chosen) == names.end()) {
            std::string list;
            for (const auto& n : names) list += (list.empty() ? "'" : ", '") + n + "'";
            throw VdbInputError("grid", fmt::format("no grid named '{}' in '{}' (it has {})", chosen, file, list));
        }
        base = f.readGrid(chosen);
        f.close();
    } catch (const openvdb::Exception& e) {
        throw VdbInputError("filename", fmt::format("cannot read '{}' as OpenVDB: {}", file, e.what()));
    }
    VdbDense d;
    d.grid_name = base->getName();
    const std::string source = fmt::format("grid '{}' of '{}'", base->getName(), file);
    if (!base->transform().isLinear())
        throw VdbInputError("filename", fmt::format("{}: only linear grid transforms are supported", source));
    openvdb::CoordBBox bb = base->evalActiveVoxelBoundingBox();
    // No active voxels (a simulation frame before any smoke): one voxel of the background value at index 0.
    if (bb.empty()) bb = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(0));
    const openvdb::Coord dim = bb.dim();
    for (int i = 0; i < 3; ++i) {
        d.res[i] = dim[i];
        d.bbox_min[i] = bb.min()[i];
    }
    if (double(d.res[0]) * d.res[1] * d.res[2] > max_voxels)
        throw VdbInputError("grid", fmt::format("{}: active bounding box {}x{}x{} is too large for a dense copy",
                                                source, d.res[0], d.res[1], d.res[2]));
    if (auto g = openvdb::gridPtrCast<openvdb::FloatGrid>(base)) {
        copy_dense<openvdb::FloatGrid, 1>(*g, bb, d);
    } else if (auto gd = openvdb::gridPtrCast<openvdb::DoubleGrid>(base)) {
        copy_dense<openvdb::DoubleGrid, 1>(*gd, bb, d);
    } else if (auto gv = openvdb::gridPtrCast<openvdb::Vec3SGrid>(base)) {
        d.channels = 3;
        copy_dense<openvdb::Vec3SGrid, 3>(*gv, bb, d);
    } else {
        throw VdbInputError("grid", fmt::format("{} has type {}; gridvolume reads float, double and vec3s grids",
                                                source, base->valueType()));
    }
    const auto& xf = base->transform();
    const openvdb::Vec3d o = xf.indexToWorld(openvdb::Vec3d(0, 0, 0));
    const openvdb::Vec3d ex = xf.indexToWorld(openvdb::Vec3d(1, 0, 0)) - o,
                         ey = xf.indexToWorld(openvdb::Vec3d(0, 1, 0)) - o,
                         ez = xf.indexToWorld(openvdb::Vec3d(0, 0, 1)) - o;
    d.index_to_world[0] = glm::dvec4(ex.x(), ex.y(), ex.z(), 0);
    d.index_to_world[1] = glm::dvec4(ey.x(), ey.y(), ey.z(), 0);
    d.index_to_world[2] = glm::dvec4(ez.x(), ez.y(), ez.z(), 0);
    d.index_to_world[3] = glm::dvec4(o.x(), o.y(), o.z(), 1);
    return d;
}

openvdb::math::Transform::Ptr lattice_transform(const VdbLattice& l) {
    openvdb::math::Mat4d m = openvdb::math::Mat4d::identity();
    m.setToScale(openvdb::Vec3d(l.spacing.x, l.spacing.y, l.spacing.z));
    m.setTranslation(openvdb::Vec3d(l.origin.x, l.origin.y, l.origin.z));  // voxel (0, 0, 0)'s centre
    return openvdb::math::Transform::createLinearTransform(m);
}

void write(const std::filesystem::path& path, const std::vector<VdbGridData>& data) {
    initialize();
    openvdb::GridPtrVec grids;
    for (const VdbGridData& d : data) {
        const int nx = d.lattice.res[0], ny = d.lattice.res[1], nz = d.lattice.res[2];
        if (d.y && d.z) {
            auto grid = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.f));
            grid->setName(d.name);
            grid->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
            grid->setTransform(lattice_transform(d.lattice));
            auto acc = grid->getAccessor();
            std::size_t c = 0;
            for (int k = 0; k < nz; ++k)
                for (int j = 0; j < ny; ++j)
                    for (int i = 0; i < nx; ++i, ++c) {
                        const Vec3d v(d.x[c], d.y[c], d.z[c]);
                        if (v != Vec3d(0.0))
                            acc.setValue(openvdb::Coord(i, j, k), openvdb::Vec3s(float(v.x), float(v.y), float(v.z)));
                    }
            grids.push_back(grid);
        } else {
            auto grid = openvdb::FloatGrid::create(0.f);
            grid->setName(d.name);
            grid->setGridClass(openvdb::GRID_FOG_VOLUME);
            grid->setTransform(lattice_transform(d.lattice));
            auto acc = grid->getAccessor();
            std::size_t c = 0;
            for (int k = 0; k < nz; ++k)
                for (int j = 0; j < ny; ++j)
                    for (int i = 0; i < nx; ++i, ++c)
                        if (const double v = d.x[c]; v != 0) acc.setValue(openvdb::Coord(i, j, k), float(v));
            grids.push_back(grid);
        }
    }
    write_atomically(path, [&](const std::filesystem::path& tmp) {
        openvdb::io::File file(tmp.string());
        file.write(grids);
        file.close();
    });
}

const VdbCodec codec{&read_float_grid, &read_dense, &write};

}  // namespace
}  // namespace kelvin::detail

// The entry point named by KELVIN_VDB_CODEC_ENTRY (core/vdb_io.h).
extern "C" __attribute__((visibility("default"))) const void* kelvin_vdb_codec_v2() { return &kelvin::detail::codec; }
