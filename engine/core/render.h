// Renders a job end to end: validate the pipeline, load the scene, build the
// ray-query acceleration structure, run the passes, write the images (EXR with
// metadata + PNG preview, atomically) and, if asked, a Chrome trace.
#pragma once

#include "engine/core/job.h"
#include "engine/core/scheduler.h"
#include "jobs/work_context.h"

#include <string>
#include <vector>

namespace fg {

class RayQuery;
struct Scene;

struct RenderOptions {
    bool showProgress = false;     // a progress bar on stderr
    std::string profilePath;       // Chrome trace-event JSON, empty = none
    std::string statsPath;         // per-pass statistics as JSON (statsJson), empty = none
    std::string commandLine;       // how the render was started, for the EXR metadata; empty = not recorded
};

struct RenderOutcome {
    RunResult run;
    double sceneSeconds = 0.0;     // scene loading
    double accelSeconds = 0.0;     // Embree build
    std::vector<std::string> files;
};

// Everything except rendering: the job's pipeline and parameters, its scene,
// and the output directory. Throws InputError.
// Runs every pass's preflight after loading the scene. Throws InputError.
ExecutionPlan validateJob(const Job& job, const Registry& registry = installedRegistry());
RenderOutcome renderJob(const Job& job, const RenderOptions& options, const Registry& registry = installedRegistry());

// A scene loaded and its Embree scene built once, for many renders of it
// (fluxgraph batch). It must be what loadScene(job.scenePath, job.sceneDefines)
// gives; sceneSeconds and accelSeconds of such a render are 0.
struct PreparedScene {
    const Scene& scene;
    const RayQuery& rays;
};
RenderOutcome renderJob(const Job& job, const RenderOptions& options, const PreparedScene& prepared,
                        const Registry& registry = installedRegistry());

// One row per pass of each repeat block: its instances summed ("block[*].name").
std::vector<PassStats> blockPassSums(const std::vector<PassStats>& stats);
// Human-readable per-pass table (wall, CPU, items, items/s, bytes).
std::string formatPassTable(const RenderOutcome& outcome);
// The run's statistics as JSON: per pass (instance, pass, start, wall, cpu,
// items, output bytes, counters) plus scene-load and Embree-build times.
std::string statsJson(const RenderOutcome& outcome);
// Chrome trace-event JSON of the given slices (times relative to the earliest).
std::string chromeTraceJson(const std::vector<jobs::TraceSlice>& slices);

}  // namespace fg
