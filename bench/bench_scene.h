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

// With area_lights, every triangle light is sampled by area
// (Scene::set_solid_angle_lights(false)): the estimator before solid-angle
// sampling, for comparisons in one run.
inline std::shared_ptr<const render::Scene> load_bench_scene(const JobSpec& spec, bool lambert,
                                                             bool area_lights = false) {
  render::SceneData data = render::load_job_scene_data(spec);
  if (lambert)
    for (render::Material& m : data.materials) {
      m.metallic = 0.0f;
      m.ior = 1.0f;
    }
  std::unique_ptr<render::Environment> env;
  if (spec.environment) env = render::Environment::from_spec(*spec.environment);
  auto scene = std::make_shared<render::Scene>(std::move(data), std::move(env));
  scene->set_solid_angle_lights(!area_lights);
  return scene;
}

}  // namespace dofarm::bench
