// The scene a renderer benchmark traces: the job's own, or with --lambert
// every material made a pure Lambert of its base colour (metallic 0, IOR 1:
// no specular layer), as in Blender's matched-material comparison
// (bench/cycles_vs_dofarm.sh).
#pragma once

#include <memory>
#include <utility>

#include "common/jobspec.h"
#include "worker/render/environment.h"
#include "worker/render/scene.h"
#include "worker/render/scene_data.h"

namespace dofarm::bench {

inline std::shared_ptr<const render::Scene> load_bench_scene(const JobSpec& spec, bool lambert) {
  if (!lambert) return render::load_scene(spec);
  render::SceneData data = render::load_scene_data(spec.scene);
  for (render::Material& m : data.materials) {
    m.metallic = 0.0f;
    m.ior = 1.0f;
  }
  std::unique_ptr<render::Environment> env;
  if (spec.environment) env = render::Environment::from_spec(*spec.environment);
  return std::make_shared<const render::Scene>(std::move(data), std::move(env));
}

}  // namespace dofarm::bench
