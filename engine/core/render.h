// Renders a job end to end: validate the pipeline, load the scene, build the
// ray-query acceleration structure, run the passes, write the images (EXR with
// metadata + PNG preview, atomically) and, if asked, a Chrome trace.
#pragma once

#include "engine/core/job.h"
#include "engine/core/scheduler.h"
#include "jobs/work_context.h"

#include <map>
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

// The steps of a render between loading the scene and running the passes, for
// other ways of running a job (fluxgraph replay).
// The job's film: the scene camera's size unless the job gives one.
FilmSettings jobFilm(const Job& job, const Scene& scene);
// The job's plan with the scene's rendering hints applied where the job is
// silent (parameters that declare a hint; the film filter, in `film`).
ExecutionPlan planWithSceneHints(const Job& job, const Scene& scene, FilmSettings& film, const Registry& registry);
// Every live pass checks the scene and its parameters, then the memory the
// passes estimate they will allocate is compared with what is available.
// Throws InputError.
void runPreflights(const ExecutionPlan& plan, const Scene& scene, const FilmSettings& film);
// The memory check alone, against `available` bytes (limited by `limitedBy`);
// `estimates` pairs each pass instance (and its source) with its estimate.
struct PassMemory {
    std::string instance, source;
    MemoryEstimate estimate;
};
void checkMemory(const std::vector<PassMemory>& estimates, std::uint64_t available, const std::string& limitedBy);
// Every live pass's estimate, of a repeat block's passes two iterations.
std::vector<PassMemory> estimateMemory(const ExecutionPlan& plan, const Scene& scene, const FilmSettings& film);
// Loads (and checks) the plan's imported buffers. Throws InputError.
std::map<std::string, BufferHandle> loadImports(const ExecutionPlan& plan);
// Throws InputError unless a file (`what`: "profile", ...) can be written at `path`.
void ensureWritableFilePath(const std::string& path, const std::string& what);
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
// `s` as the inside of a JSON string literal (quotes, backslashes and control
// characters escaped).
std::string jsonEscape(const std::string& s);
// Chrome trace-event JSON of the given slices (times relative to the earliest).
std::string chromeTraceJson(const std::vector<jobs::TraceSlice>& slices);

}  // namespace fg
