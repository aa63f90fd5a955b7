#include "tests/support/render_helpers.h"

#include "passes/passes.h"
#include "engine/accel/ray_query.h"
#include "jobs/parallel.h"

#include <stdexcept>

namespace fg::test {

Rgb RenderedImage::mean() const {
    glm::dvec3 sum(0.0);
    for (const Rgb& p : pixels) sum += glm::dvec3(p);
    return Rgb(sum / static_cast<double>(std::max<std::size_t>(1, pixels.size())));
}

RenderedImage renderPipeline(const Scene& scene, const std::string& pipeline,
                             const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                             std::uint64_t seed, int threads) {
    const Pipeline* p = findPipeline(pipeline);
    if (!p) throw std::invalid_argument("no pipeline " + pipeline);
    JobParams jobParams;
    for (const auto& [key, value] : params) {
        const auto dot = key.find('.');
        jobParams.values[key.substr(0, dot)][key.substr(dot + 1)] = {value, "test"};
    }
    const ExecutionPlan plan = ExecutionPlan::build(*p, jobParams, "test");
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = film;
    const RunResult result = execute(plan, scene, rays, options);
    const Film& image = *static_cast<const Film*>(result.results.at("image").data.get());
    return {image.width(), image.height(), image.resolve()};
}

}  // namespace fg::test
