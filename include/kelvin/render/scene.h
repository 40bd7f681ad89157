#pragma once
// The scene: shapes in one committed Embree scene, the sensor, the integrator; or a simulation. It is the
// Job that `kelvin scene.xml` runs. Geometry is only built when the scene has shapes.
#include <kelvin/core/job.h>
#include <kelvin/render/emitter.h>
#include <kelvin/render/integrator.h>
#include <kelvin/render/interaction.h>
#include <kelvin/render/ray.h>
#include <kelvin/render/sensor.h>
#include <kelvin/render/shape.h>

#include <memory>
#include <optional>
#include <vector>

namespace kelvin {

class Scene : public Job {
public:
    explicit Scene(const Properties& props);
    ~Scene() override;

    RunResult run(RunContext& ctx) override;
    bool distributable() const override;
    /// The integrator's (or simulation's) description.
    std::string description() const override;

    /// Closest hit along the ray within [tmin, tmax], or nullopt.
    std::optional<SurfaceHit> intersect(const Ray& ray) const;
    /// True if anything blocks the ray within [tmin, tmax].
    bool occluded(const Ray& ray) const;
    /// The full interaction at a hit of `ray`: shading normal (interpolated vertex normals), uv, frame, and
    /// wi = -ray.d in the shading frame.
    SurfaceInteraction interaction(const Ray& ray, const SurfaceHit& hit) const;

    /// Every emitter: shape-attached area emitters first (in shape order), then the root's emitters.
    const std::vector<const Emitter*>& emitters() const { return m_emitters; }
    /// Emitters seen by rays that leave the scene (constant, envmap).
    const std::vector<const Emitter*>& environment_emitters() const { return m_env_emitters; }
    /// Pick an emitter for next-event estimation with `u`; returns it and its selection probability.
    std::pair<const Emitter*, double> sample_emitter(double u) const;
    /// Probability that sample_emitter picks `e`.
    double emitter_pdf(const Emitter* e) const;

    /// The scene's own shapes (declaration order). Instanced shapes are not among them: a hit's shape is
    /// shape_of(hit), and SurfaceHit::shape indexes the shapes first, then each instance's group in turn.
    const std::vector<std::shared_ptr<Shape>>& shapes() const { return m_shapes; }
    const Shape& shape_of(const SurfaceHit& hit) const;
    /// Number of instances (shapegroup placements).
    std::size_t instance_count() const;
    const Sensor* sensor() const { return m_sensor.get(); }
    Integrator* integrator() const { return m_integrator.get(); }
    /// The <simulation> the scene runs instead of a render (null for a render); fluid/simulation.h's
    /// find_simulation gives it as a fluid::Simulation.
    const std::shared_ptr<Job>& simulation() const { return m_simulation; }
    std::shared_ptr<Job> delegate() const override { return m_simulation; }
    /// Axis-aligned bounds of all geometry (empty box if none).
    std::pair<Vec3d, Vec3d> bounds() const { return {m_bbox_min, m_bbox_max}; }

private:
    void setup_emitters();
    struct Accel;
    std::vector<std::shared_ptr<Shape>> m_shapes;
    std::vector<std::shared_ptr<const ShapeInstance>> m_instances;  // keep their groups (and shapes) alive
    std::shared_ptr<Sensor> m_sensor;
    std::shared_ptr<Integrator> m_integrator;
    std::shared_ptr<Job> m_simulation;
    std::vector<std::shared_ptr<Emitter>> m_root_emitters;
    std::vector<const Emitter*> m_emitters, m_env_emitters;
    std::unique_ptr<Accel> m_accel;
    Vec3d m_bbox_min{Inf}, m_bbox_max{-Inf};
};

}  // namespace kelvin
