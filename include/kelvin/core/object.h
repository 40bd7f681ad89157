#pragma once
// Base class of every plugin object (integrators, shapes, mutations, velocity estimators, ...).
#include <memory>
#include <string>

namespace kelvin {

class Object;
using ObjectPtr = std::shared_ptr<Object>;

class Object {
public:
    virtual ~Object() = default;
    /// Plugin kind ("integrator", "shape", ...) and name ("path", "sphere", ...), set by the registry.
    const std::string& plugin_kind() const { return m_kind; }
    const std::string& plugin_name() const { return m_name; }
    /// The id= given in the scene, or empty.
    const std::string& id() const { return m_id; }
    virtual std::string to_string() const;
    /// A short human-readable name for run summaries and output metadata: the plugin name and, where the plugin
    /// has variants, the variant ("drmlt (orbital, Tierney–Mira)"). Default: plugin_name().
    virtual std::string description() const { return m_name; }

private:
    friend class Registry;
    std::string m_kind, m_name, m_id;
};

}  // namespace kelvin
