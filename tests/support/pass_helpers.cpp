#include "tests/support/pass_helpers.h"

#include "engine/accel/ray_query.h"
#include "jobs/parallel.h"

#include <stdexcept>

namespace fg::test {

std::map<std::string, BufferHandle> runPass(const PassRegistration& pass, const Scene& scene, const RayQuery* rays,
                                            const FilmSettings& film, std::map<std::string, BufferHandle> inputs,
                                            const std::map<std::string, ParamValue>& params, std::uint64_t seed) {
    PassParams resolved;
    for (const ParamSpec& p : pass.spec.params) resolved.set(p.name, p.defaultValue);
    for (const auto& [name, value] : params) resolved.set(name, value);
    std::map<std::string, BufferHandle*> in;
    for (const SlotSpec& slot : pass.spec.inputs) {
        const auto it = inputs.find(slot.name);
        if (it == inputs.end() && slot.optional) {
            in[slot.name] = nullptr;  // absent, as the scheduler leaves an optional input nobody produces
            continue;
        }
        if (it == inputs.end()) throw std::invalid_argument("runPass: no buffer for input '" + slot.name + "'");
        in[slot.name] = &it->second;
    }
    std::map<std::string, BufferHandle> outputs;
    std::map<std::string, BufferHandle*> out;
    for (const SlotSpec& slot : pass.spec.outputs) {
        outputs[slot.name].type = slot.type;
        out[slot.name] = &outputs[slot.name];
    }
    PassContext ctx(scene, rays, film, seed, resolved, in, out, pass.spec.name);
    // As the scheduler does with stored inputs: a streamable input arrives as one batch.
    const std::unique_ptr<Pass> instance = pass.create();
    for (const SlotSpec& slot : pass.spec.inputs)
        if (slot.streamable && in[slot.name]) instance->consumeBatch(ctx, slot.name);
    instance->run(ctx);
    return outputs;
}

BufferHandle runPipeline(const Scene& scene, const Pipeline& pipeline, const std::vector<PassRegistration>& registry,
                         const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                         const std::string& result, std::uint64_t seed, int threads) {
    JobParams jobParams;
    for (const auto& [key, value] : params) {
        const auto dot = key.find('.');
        jobParams.values[key.substr(0, dot)][key.substr(dot + 1)] = {value, "test"};
    }
    Pipeline withResult = pipeline;
    withResult.results = {result};
    const ExecutionPlan plan = ExecutionPlan::build(withResult, jobParams, "test", registry);
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = film;
    RunResult run = execute(plan, scene, rays, options);
    return run.results.at(result);
}

}  // namespace fg::test
