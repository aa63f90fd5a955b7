// End-to-end rendering of a job, and the reports a run leaves behind: the
// per-pass table, the EXR metadata and the Chrome trace (chrome://tracing or
// ui.perfetto.dev: one slice per pass, one per task chunk, a row per thread).
#include "engine/core/render.h"

#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/interrupt.h"
#include "engine/core/output_files.h"
#include "engine/image/image_io.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene_loader.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <sstream>
#include <unistd.h>

namespace fg {

namespace {

namespace fs = std::filesystem;

// Writes and removes a probe file: permission bits alone do not tell (root,
// ACLs, read-only mounts).
bool canCreateFileIn(const fs::path& dir) {
    const fs::path probe = dir / (".fluxgraph-write-test-" + std::to_string(::getpid()));
    registerTemporaryFile(probe.string());
    bool written = false;
    {
        std::ofstream out(probe);
        written = out && (out << "x") && out.flush();
    }
    std::error_code ignored;
    fs::remove(probe, ignored);
    unregisterCleanupPath(probe.string());
    return written;
}

// Creates the output directory if needed and proves it is writable, before any
// work is done, so that a long render never fails at the very end. `outputs`
// remembers the directories it creates, to remove them if the run fails.
void ensureWritableDirectory(const std::string& dir, OutputCommit& outputs) {
    outputs.createDirectories(dir);
    if (!canCreateFileIn(dir)) throw InputError(dir + ": output directory is not writable");
}


std::string humanBytes(std::size_t bytes) {
    std::ostringstream out;
    out << std::fixed << std::setprecision(1);
    if (bytes >= (1u << 30)) out << static_cast<double>(bytes) / (1u << 30) << " GiB";
    else if (bytes >= (1u << 20)) out << static_cast<double>(bytes) / (1u << 20) << " MiB";
    else if (bytes >= (1u << 10)) out << static_cast<double>(bytes) / (1u << 10) << " KiB";
    else out << bytes << " B";
    return out.str();
}

// Progress bar on stderr, one line per pass, redrawn at most every percent.
class ProgressBar {
public:
    void update(const std::string& pass, double fraction) {
        std::lock_guard lock(mutex_);
        const int percent = static_cast<int>(fraction * 100.0);
        if (pass == pass_ && percent == percent_) return;
        if (pass != pass_ && !pass_.empty()) std::fputc('\n', stderr);
        pass_ = pass;
        percent_ = percent;
        const int filled = percent * 30 / 100;
        std::fprintf(stderr, "\r%-12s [%s%s] %3d%%", pass.c_str(), std::string(static_cast<std::size_t>(filled), '#').c_str(),
                     std::string(static_cast<std::size_t>(30 - filled), '.').c_str(), percent);
        std::fflush(stderr);
    }
    void finish() {
        std::lock_guard lock(mutex_);
        if (!pass_.empty()) std::fputc('\n', stderr);
    }

private:
    std::mutex mutex_;
    std::string pass_;
    int percent_ = -1;
};

std::string pipelineDescription(const ExecutionPlan& plan) {
    std::string text = plan.pipeline().name + ":";
    for (int i : plan.topologicalOrder()) {
        const PlannedPass& p = plan.passes()[static_cast<std::size_t>(i)];
        text += " " + p.node.instance + (p.culled ? "(culled)" : "");
    }
    return text;
}

}  // namespace

// Traces, statistics and saved buffers are written during or after the
// render; their destinations are checked before it.
void ensureWritableFilePath(const std::string& path, const std::string& what) {
    const fs::path parent = fs::path(path).has_parent_path() ? fs::path(path).parent_path() : fs::path(".");
    std::error_code ec;
    if (fs::is_directory(path, ec)) throw InputError(path + ": cannot write " + what + ": is a directory");
    if (!fs::is_directory(parent, ec))
        throw InputError(path + ": cannot write " + what + ": no directory " + parent.string());
    if (!canCreateFileIn(parent)) throw InputError(path + ": cannot write " + what + ": directory is not writable");
}

// Scene files may carry rendering hints (Mitsuba's sample_count, max_depth,
// rfilter). They fill in what the job leaves unsaid, and only for parameters
// that declare they take that hint (ParamSpec::sceneHint): the path tracer's
// depth, not the photon pass's. The film filter comes from the scene when the
// job has no [film] filter. The job file always wins.
ExecutionPlan planWithSceneHints(const Job& job, const Scene& scene, FilmSettings& film, const Registry& registry) {
    JobParams params = job.params;
    const RenderHints& hints = scene.hints;
    const std::string source = job.scenePath + " (scene hint)";
    const auto addHints = [&](const PipelineNode& node) {
        const PassRegistration* registration = registry.findPass(node.pass);
        if (!registration) return;  // build() reports it
        auto& values = params.values[node.instance];
        for (const ParamSpec& p : registration->spec.params) {
            if (values.count(p.name)) continue;
            if (p.sceneHint == "sample_count" && hints.samplesPerPixel > 0)
                values[p.name] = {std::int64_t{hints.samplesPerPixel}, source};
            if (p.sceneHint == "max_depth" && hints.maxDepth > 0)
                values[p.name] = {std::int64_t{hints.maxDepth}, source};
        }
        if (values.empty()) params.values.erase(node.instance);
    };
    for (const PipelineNode& node : job.pipeline.nodes) addHints(node);
    for (const RepeatBlock& block : job.pipeline.blocks)
        for (const PipelineNode& node : block.nodes) addHints(node);
    if (hints.filter && !job.filmFilterGiven) {
        film.filter = *hints.filter;
        if (hints.filterRadius > 0.0f) film.filterRadius = hints.filterRadius;
        if (hints.gaussianSigma > 0.0f) film.gaussianSigma = hints.gaussianSigma;
    }
    return ExecutionPlan::build(job.pipeline, params, job.path, registry.passes, job.bufferFiles);
}

// The whole job's estimate is the sum over the live pass instances (two
// iterations of a repeat block), as if every buffer lived from the first pass
// to the last. Buffers freed after their last reader make the real peak
// lower; the sum is simple and errs towards refusing, and refusing a job that
// would just have fitted costs a minute, while one that does not fit costs
// the machine (swapping, the OOM killer).
void checkMemory(const std::vector<PassMemory>& estimates, std::uint64_t available, const std::string& limitedBy) {
    std::uint64_t total = 0;
    const PassMemory* largest = nullptr;
    for (const PassMemory& e : estimates) {
        total = addBytes(total, e.estimate.bytes);
        if (!largest || e.estimate.bytes > largest->estimate.bytes) largest = &e;
    }
    if (!largest || total <= available) return;
    std::string message = largest->source + ": pass '" + largest->instance + "' needs about " +
                          describeBytes(largest->estimate.bytes) + " (" + largest->estimate.what + ")";
    if (total != largest->estimate.bytes) message += ", the job about " + describeBytes(total) + " in all";
    message += ", but only " + describeBytes(available) + " is available (" + limitedBy + ")";
    if (!largest->estimate.hint.empty()) message += "; " + largest->estimate.hint;
    throw InputError(message);
}

// Every live pass checks the scene and its parameters before any work.
namespace {

// Calls `visit` with every live pass and the context its preflight and memory
// estimate see.
void forEachLivePass(const ExecutionPlan& plan, const Scene& scene, const FilmSettings& film,
                     const std::function<void(const PlannedPass&, const PreflightContext&)>& visit) {
    const auto& passes = plan.passes();
    for (const PlannedPass& p : passes) {
        if (p.culled) continue;
        const auto producerOf = [&](const std::string& slot) -> const PlannedPass* {
            const auto it = p.node.inputBindings.find(slot);
            if (it == p.node.inputBindings.end() || it->second.empty()) return nullptr;
            for (const PlannedPass& q : passes)
                for (const auto& [outSlot, version] : q.node.outputBindings)
                    if (version == it->second) return &q;
            return nullptr;
        };
        const PreflightContext context{
            scene, p.params, p.paramsKey, p.source,
            [&](const std::string& slot) -> const PassParams* {
                const PlannedPass* producer = producerOf(slot);
                return producer ? &producer->params : nullptr;
            },
            [&](const std::string& slot) -> std::string {
                const PlannedPass* producer = producerOf(slot);
                return producer ? producer->node.pass : std::string();
            },
            film,
            [&](const std::string& slot) {
                const auto it = p.node.outputBindings.find(slot);
                return it != p.node.outputBindings.end() && !it->second.empty() && plan.streamed(it->second);
            }};
        visit(p, context);
    }
}

}  // namespace

std::vector<PassMemory> estimateMemory(const ExecutionPlan& plan, const Scene& scene, const FilmSettings& film) {
    std::vector<PassMemory> estimates;
    std::map<std::string, int> iterationsCounted;
    forEachLivePass(plan, scene, film, [&](const PlannedPass& p, const PreflightContext& context) {
        // Iteration i + 1 of a block starts once all of iteration i is done,
        // and what it does not carry on is freed: at most two iterations'
        // buffers (the running one's and those carried from the one before)
        // are alive at once.
        if (p.registration->memory && ++iterationsCounted[p.paramsKey] <= 2)
            estimates.push_back({p.node.instance, p.source, p.registration->memory(context)});
    });
    return estimates;
}

void runPreflights(const ExecutionPlan& plan, const Scene& scene, const FilmSettings& film) {
    std::set<std::string> checked;  // a block pass is checked once, not once per iteration
    forEachLivePass(plan, scene, film, [&](const PlannedPass& p, const PreflightContext& context) {
        if (p.registration->preflight && checked.insert(p.paramsKey).second) p.registration->preflight(context);
    });
    if (const auto available = availableMemory())
        checkMemory(estimateMemory(plan, scene, film), available->bytes, available->limitedBy);
}

// Imported buffers are loaded (and checked) before any work.
std::map<std::string, BufferHandle> loadImports(const ExecutionPlan& plan) {
    std::map<std::string, BufferHandle> loaded;
    for (const auto& [version, typeAndPath] : plan.imports())
        loaded[version] = loadBuffer(typeAndPath.second, typeAndPath.first, version);
    return loaded;
}

FilmSettings jobFilm(const Job& job, const Scene& scene) {
    FilmSettings film = job.film;
    if (!job.filmSizeGiven) {
        film.width = scene.camera.width;
        film.height = scene.camera.height;
    }
    return film;
}

std::string jsonEscape(const std::string& s) {
    std::string out;
    for (char c : s) {
        switch (c) {
        case '"': out += "\\\""; break;
        case '\\': out += "\\\\"; break;
        case '\n': out += "\\n"; break;
        case '\t': out += "\\t"; break;
        default:
            if (static_cast<unsigned char>(c) < 0x20) {
                char buf[8];
                std::snprintf(buf, sizeof buf, "\\u%04x", c);
                out += buf;
            } else {
                out += c;
            }
        }
    }
    return out;
}

namespace {

// The checks loadImports makes before decoding (type, codec version, size),
// run before the scene loads so that a bad import is refused at once, by
// validate and render alike, with the line loading would give.
void checkImportFiles(const ExecutionPlan& plan) {
    for (const auto& [version, typeAndPath] : plan.imports())
        checkBufferFile(typeAndPath.second, typeAndPath.first, version);
}

}  // namespace

ExecutionPlan validateJob(const Job& job, const Registry& registry) {
    checkImportFiles(ExecutionPlan::build(job.pipeline, job.params, job.path, registry.passes, job.bufferFiles));
    const Scene scene = loadScene(job.scenePath, job.sceneDefines);
    FilmSettings film = jobFilm(job, scene);
    ExecutionPlan plan = planWithSceneHints(job, scene, film, registry);
    runPreflights(plan, scene, film);
    return plan;
}

namespace {

// `prepared` null: the scene is loaded and its Embree scene built here.
RenderOutcome renderWith(const Job& job, const RenderOptions& options, const PreparedScene* prepared,
                         const Registry& registry) {
    // Validated before anything slow happens; rebuilt below with the scene's hints.
    checkImportFiles(ExecutionPlan::build(job.pipeline, job.params, job.path, registry.passes, job.bufferFiles));
    // Every output goes to a temporary first; all are renamed at the end, or
    // none (and the directories made for them are removed again).
    OutputCommit outputs;
    ensureWritableDirectory(job.output.directory, outputs);
    if (!options.profilePath.empty()) ensureWritableFilePath(options.profilePath, "profile");
    if (!options.statsPath.empty()) ensureWritableFilePath(options.statsPath, "statistics");

    RenderOutcome outcome;
    const std::int64_t t0 = jobs::wallNanos();
    std::optional<Scene> ownScene;
    if (!prepared) ownScene.emplace(loadScene(job.scenePath, job.sceneDefines));
    const Scene& scene = prepared ? prepared->scene : *ownScene;
    const std::int64_t t1 = jobs::wallNanos();
    outcome.sceneSeconds = 1e-9 * static_cast<double>(t1 - t0);

    FilmSettings film = jobFilm(job, scene);
    const ExecutionPlan plan = planWithSceneHints(job, scene, film, registry);
    runPreflights(plan, scene, film);
    std::map<std::string, BufferHandle> imported = loadImports(plan);
    for (const auto& [version, path] : plan.saves()) ensureWritableFilePath(path, "saved buffer");
    const jobs::ThreadLimit threadLimit(job.threads);
    std::optional<RayQuery> ownRays;
    if (!prepared) ownRays.emplace(scene);
    const RayQuery& rays = prepared ? prepared->rays : *ownRays;
    outcome.accelSeconds = 1e-9 * static_cast<double>(jobs::wallNanos() - t1);

    ProgressBar bar;
    RunOptions runOptions;
    runOptions.seed = job.seed;
    runOptions.film = film;
    runOptions.imported = std::move(imported);
    std::mutex savedFilesMutex;
    runOptions.save = [&](const std::string& version, const std::string& path, const BufferHandle& buffer) {
        writeBufferFile(buffer, path, outputs.stage(path), job.text);
        const std::lock_guard lock(savedFilesMutex);
        outcome.files.push_back(path);
        (void)version;
    };
    if (options.showProgress) runOptions.progress = [&bar](const std::string& p, double f) { bar.update(p, f); };
    auto& recorder = jobs::TraceRecorder::instance();
    recorder.setEnabled(!options.profilePath.empty());
    recorder.take();
    pauseForTest("start");
    outcome.run = execute(plan, scene, rays, runOptions);
    // All the work is done: from here on an interrupt keeps it (also in a
    // pipeline whose passes report no units of their own).
    noteCompletedUnit();
    recorder.setEnabled(false);
    if (options.showProgress) bar.finish();

    // Outputs: one EXR (+ PNG) per result buffer.
    std::ostringstream timings;
    for (const PassStats& s : outcome.run.stats) {
        timings << s.instance << ": wall " << s.wallSeconds << " s, cpu " << s.cpuSeconds << " s, items " << s.items
                << "\n";
    }
    Metadata metadata = {
        {"version", FLUXGRAPH_VERSION},
        {"job", job.text},
        {"job_path", job.path},
        {"scene", job.scenePath},
        {"pipeline", pipelineDescription(plan)},
        {"seed", std::to_string(job.seed)},
        {"threads", std::to_string(jobs::maxThreads())},
        {"pass_timings", timings.str()},
    };
    std::string iterations;
    for (const auto& [block, count] : outcome.run.iterations)
        iterations += (iterations.empty() ? "" : " ") + block + "=" + std::to_string(count);
    // A time budget is not deterministic: the count run is what reproduces the image.
    if (!iterations.empty()) metadata.emplace_back("iterations", iterations);
    std::string overrides;
    for (const std::string& o : job.overrides) overrides += (overrides.empty() ? "" : " ") + o;
    if (!overrides.empty()) metadata.emplace_back("overrides", overrides);
    std::string defines;
    for (const auto& [name, value] : job.sceneDefines) defines += (defines.empty() ? "" : " ") + name + "=" + value;
    if (!defines.empty()) metadata.emplace_back("scene_defines", defines);
    if (!options.commandLine.empty()) metadata.emplace_back("command", options.commandLine);
    // An interrupted render keeps what was done; the file says so, and how much.
    if (!outcome.run.partial.empty()) {
        std::string completed;
        for (const std::string& part : outcome.run.partial) completed += (completed.empty() ? "" : "; ") + part;
        metadata.emplace_back("partial", "true");
        metadata.emplace_back("completed", completed);
    }

    for (const std::string& result : job.pipeline.results) {
        const BufferHandle& handle = outcome.run.results.at(result);
        if (handle.type != "Film") continue;
        const Film& image = *static_cast<const Film*>(handle.data.get());
        ImageChannels channels;
        channels.width = image.width();
        channels.height = image.height();
        channels.rgb = image.resolve();
        channels.extra = image.aovs();
        const std::string stem = job.pipeline.results.size() == 1 ? job.output.name : job.output.name + "-" + result;
        const fs::path base = fs::path(job.output.directory) / stem;
        const auto writeImage = [&](const std::string& path, const std::vector<unsigned char>& encoded) {
            writeFileChecked(path, outputs.stage(path),
                             std::string_view(reinterpret_cast<const char*>(encoded.data()), encoded.size()));
            outcome.files.push_back(path);
        };
        if (job.output.exr) {
            const std::string path = base.string() + ".exr";
            writeImage(path, encodeExr(path, channels, metadata, job.output.half));
        }
        if (job.output.png) {
            const std::string path = base.string() + ".png";
            writeImage(path, encodePngPreview(path, channels, job.output.exposure));
        }
    }
    if (!options.profilePath.empty()) {
        writeFileChecked(options.profilePath, outputs.stage(options.profilePath), chromeTraceJson(recorder.take()));
        outcome.files.push_back(options.profilePath);
    }
    if (!options.statsPath.empty()) {
        outcome.files.push_back(options.statsPath);
        writeFileChecked(options.statsPath, outputs.stage(options.statsPath), statsJson(outcome));
    }
    outputs.commit();
    return outcome;
}

}  // namespace

RenderOutcome renderJob(const Job& job, const RenderOptions& options, const Registry& registry) {
    return renderWith(job, options, nullptr, registry);
}

RenderOutcome renderJob(const Job& job, const RenderOptions& options, const PreparedScene& prepared,
                        const Registry& registry) {
    return renderWith(job, options, &prepared, registry);
}

std::vector<PassStats> blockPassSums(const std::vector<PassStats>& stats) {
    std::vector<PassStats> sums;
    std::map<std::pair<std::string, std::string>, std::size_t> row;
    for (const PassStats& s : stats) {
        if (s.block.empty()) continue;
        const auto key = std::make_pair(s.block, s.blockPass);
        auto [it, added] = row.emplace(key, sums.size());
        if (added) {
            PassStats sum;
            sum.instance = s.block + "[*]." + s.blockPass;
            sum.pass = s.pass;
            sum.block = s.block;
            sum.blockPass = s.blockPass;
            sum.startSeconds = s.startSeconds;
            sums.push_back(sum);
        }
        PassStats& sum = sums[it->second];
        sum.wallSeconds += s.wallSeconds;
        sum.cpuSeconds += s.cpuSeconds;
        sum.items += s.items;
        sum.outputBytes = std::max(sum.outputBytes, s.outputBytes);
        sum.batchesEmitted += s.batchesEmitted;
        for (const auto& [name, value] : s.counters) sum.counters[name] += value;
        ++sum.counters["instances"];
    }
    return sums;
}

std::string formatPassTable(const RenderOutcome& outcome) {
    std::ostringstream out;
    std::size_t width = 16;
    for (const PassStats& s : outcome.run.stats) width = std::max(width, s.instance.size() + 2);
    out << std::left << std::setw(static_cast<int>(width)) << "pass" << std::right << std::setw(10) << "wall s"
        << std::setw(10) << "cpu s" << std::setw(8) << "cpu/w" << std::setw(14) << "items" << std::setw(14)
        << "items/s" << std::setw(12) << "out bytes" << "\n";
    out << std::fixed;
    const auto row = [&](const PassStats& s) {
        const double rate = s.wallSeconds > 0 ? static_cast<double>(s.items) / s.wallSeconds : 0.0;
        out << std::left << std::setw(static_cast<int>(width)) << s.instance << std::right << std::setprecision(3)
            << std::setw(10) << s.wallSeconds << std::setw(10) << s.cpuSeconds << std::setprecision(2) << std::setw(8)
            << (s.wallSeconds > 0 ? s.cpuSeconds / s.wallSeconds : 0.0) << std::setw(14) << s.items
            << std::setprecision(0) << std::setw(14) << rate << std::setw(12) << humanBytes(s.outputBytes) << "\n";
    };
    for (const PassStats& s : outcome.run.stats) row(s);
    for (const PassStats& s : blockPassSums(outcome.run.stats)) row(s);
    for (const auto& [block, count] : outcome.run.iterations) out << "repeat " << block << ": " << count << " iterations\n";
    out << std::setprecision(3) << "scene load " << outcome.sceneSeconds << " s, Embree build " << outcome.accelSeconds
        << " s, passes " << outcome.run.wallSeconds << " s\n";
    return out.str();
}

std::string statsJson(const RenderOutcome& outcome) {
    std::ostringstream out;
    out << std::setprecision(9) << "{\"scene_seconds\": " << outcome.sceneSeconds
        << ", \"accel_seconds\": " << outcome.accelSeconds << ", \"passes_seconds\": " << outcome.run.wallSeconds;
    const auto list = [&](const char* key, const std::vector<PassStats>& rows) {
        out << ", \"" << key << "\": [";
        for (std::size_t i = 0; i < rows.size(); ++i) {
            const PassStats& s = rows[i];
            out << (i ? "," : "") << "\n  {\"instance\": \"" << jsonEscape(s.instance) << "\", \"pass\": \""
                << jsonEscape(s.pass) << "\", ";
            if (!s.block.empty()) out << "\"block\": \"" << jsonEscape(s.block) << "\", ";
            out << "\"start_seconds\": " << s.startSeconds << ", \"wall_seconds\": " << s.wallSeconds
                << ", \"cpu_seconds\": " << s.cpuSeconds << ", \"items\": " << s.items
                << ", \"output_bytes\": " << s.outputBytes << ", \"counters\": {";
            bool first = true;
            for (const auto& [name, value] : s.counters) {
                out << (first ? "" : ", ") << "\"" << jsonEscape(name) << "\": " << value;
                first = false;
            }
            out << "}}";
        }
        out << "\n]";
    };
    list("passes", outcome.run.stats);
    list("block_passes", blockPassSums(outcome.run.stats));
    out << ", \"iterations\": {";
    bool first = true;
    for (const auto& [block, count] : outcome.run.iterations) {
        out << (first ? "" : ", ") << "\"" << jsonEscape(block) << "\": " << count;
        first = false;
    }
    out << "}}\n";
    return out.str();
}

std::string chromeTraceJson(const std::vector<jobs::TraceSlice>& slices) {
    std::int64_t origin = INT64_MAX;
    for (const auto& s : slices) origin = std::min(origin, s.beginNs);
    std::ostringstream out;
    out << "{\"displayTimeUnit\":\"ms\",\"traceEvents\":[";
    bool first = true;
    for (const auto& s : slices) {
        out << (first ? "" : ",") << "\n{\"name\":\"" << jsonEscape(s.name) << "\",\"cat\":\"" << s.category
            << "\",\"ph\":\"X\",\"pid\":1,\"tid\":" << s.thread << ",\"ts\":" << std::fixed << std::setprecision(3)
            << 1e-3 * static_cast<double>(s.beginNs - origin) << ",\"dur\":"
            << 1e-3 * static_cast<double>(s.endNs - s.beginNs) << ",\"args\":{\"items\":" << s.items << "}}";
        first = false;
    }
    out << "\n]}\n";
    return out.str();
}

}  // namespace fg
