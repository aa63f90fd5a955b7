// Replay of one pass instance (see replay.h). The inputs come from a plan
// restricted to them (ExecutionPlan::producing), so the passes that make them
// run exactly as in a render: same parameters, scene hints, seeds and
// instance names, hence the same random streams.
#include "engine/run/replay.h"

#include "engine/accel/ray_query.h"
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/render.h"
#include "engine/image/image_io.h"
#include "engine/scene/scene_loader.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <optional>
#include <string_view>
#include <sstream>
#include <unistd.h>

namespace fg {

namespace {

namespace fs = std::filesystem;

const PlannedPass& findInstance(const ExecutionPlan& plan, const std::string& instance, const std::string& origin) {
    for (const PlannedPass& p : plan.passes())
        if (p.node.instance == instance) return p;
    std::string known;
    for (const PlannedPass& p : plan.passes()) known += (known.empty() ? "" : ", ") + p.node.instance;
    throw InputError(origin + ": pipeline '" + plan.pipeline().name + "' has no pass instance '" + instance +
                     "' (instances: " + known + ")");
}

// The slots that read a buffer, each with its declared type: inputs, then in-out slots.
std::vector<std::pair<const SlotSpec*, bool>> readSlots(const PassSpec& spec) {
    std::vector<std::pair<const SlotSpec*, bool>> slots;
    for (const SlotSpec& s : spec.inputs) slots.emplace_back(&s, false);
    for (const SlotSpec& s : spec.inouts) slots.emplace_back(&s, true);
    return slots;
}

std::string inputPath(const std::string& directory, const std::string& version) {
    return (fs::path(directory) / replayInputFileName(version)).string();
}

double median(std::vector<double> values) {
    std::sort(values.begin(), values.end());
    const std::size_t n = values.size();
    if (n == 0) return 0.0;
    return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

// A private directory for copies of in-out inputs, removed with the object.
class ScratchDirectory {
public:
    ScratchDirectory() {
        path_ = fs::temp_directory_path() / ("fluxgraph-replay-" + std::to_string(::getpid()));
        fs::create_directories(path_);
    }
    ~ScratchDirectory() {
        std::error_code ignored;
        fs::remove_all(path_, ignored);
    }
    ScratchDirectory(const ScratchDirectory&) = delete;
    ScratchDirectory& operator=(const ScratchDirectory&) = delete;
    std::string file(const std::string& name) const { return (path_ / name).string(); }

private:
    fs::path path_;
};

}  // namespace

std::string replayInputFileName(const std::string& version) {
    std::string name = version;
    if (const auto block = name.rfind("]."); block != std::string::npos) name = name.substr(block + 2);
    if (const auto suffix = name.find('@'); suffix != std::string::npos) name = name.substr(0, suffix);
    return name + ".fgbuf";
}

std::string encodeBuffer(const BufferHandle& buffer) {
    const BufferCodec* codec = findCodec(buffer.type);
    if (!codec) throw std::logic_error("no codec for buffer type '" + buffer.type + "'");
    if (!buffer.data) throw std::logic_error("a " + buffer.type + " buffer holds no data");
    CodecWriter writer;
    codec->write(buffer.data.get(), writer);
    std::ostringstream out(std::ios::binary);
    out << buffer.type << '\n';
    for (const CodecColumn& column : writer.columns())
        out << column.name << ' ' << column.elementSize << ' ' << column.count << '\n';
    out << writer.itemCount() << '\n';
    writer.writePayload(out);
    return out.str();
}

std::string comparableEncoding(const BufferHandle& buffer) {
    if (buffer.type != BufferTypeName<Film>::value || !buffer.data) return encodeBuffer(buffer);
    const Film& film = *static_cast<const Film*>(buffer.data.get());
    const auto measured = [](const std::string& name) {
        constexpr std::string_view kSuffix = "time_ns";
        return name.size() >= kSuffix.size() && name.compare(name.size() - kSuffix.size(), kSuffix.size(), kSuffix) == 0;
    };
    if (std::none_of(film.aovs().begin(), film.aovs().end(), [&](const auto& aov) { return measured(aov.first); }))
        return encodeBuffer(buffer);
    Film copy = film;
    for (const auto& [name, values] : film.aovs())
        if (measured(name)) std::fill(copy.aov(name).begin(), copy.aov(name).end(), 0.0f);
    return encodeBuffer(makeBufferHandle(std::move(copy)));
}

ReplayResult replayPass(const Job& job, const ReplayOptions& options, const Registry& registry) {
    // Everything that can be wrong with the request is found before the scene loads.
    const ExecutionPlan unhinted = ExecutionPlan::build(job.pipeline, job.params, job.path, registry.passes, job.bufferFiles);
    findInstance(unhinted, options.instance, job.path);
    if (options.repeat < 1)
        throw InputError("--repeat " + std::to_string(options.repeat) + ": must be at least 1");
    const bool loadInputs = !options.inputsDirectory.empty();
    if (loadInputs) {
        const PlannedPass& target = findInstance(unhinted, options.instance, job.path);
        for (const auto& [slot, inout] : readSlots(target.registration->spec)) {
            const std::string& version = target.node.inputBindings.at(slot->name);
            if (version.empty()) continue;
            const std::string path = inputPath(options.inputsDirectory, version);
            const BufferFileInfo info = readBufferInfo(path);
            if (info.type != slot->type)
                throw InputError(path + ": holds a " + info.type + " buffer, but input '" + slot->name + "' of '" +
                                 options.instance + "' reads a " + slot->type);
            // The codec's version and the file's size too, as validate checks
            // imports: a file loading would refuse is refused before the scene.
            checkBufferFile(path, slot->type, version);
        }
    } else {
        for (const auto& [version, typeAndPath] : unhinted.imports())
            checkBufferFile(typeAndPath.second, typeAndPath.first, version);
    }
    if (!options.saveInputsDirectory.empty()) {
        std::error_code ec;
        fs::create_directories(options.saveInputsDirectory, ec);
        if (ec || !fs::is_directory(options.saveInputsDirectory, ec))
            throw InputError(options.saveInputsDirectory + ": cannot create directory for the inputs");
        ensureWritableFilePath((fs::path(options.saveInputsDirectory) / "inputs.fgbuf").string(), "inputs");
    }
    if (!options.profilePath.empty()) ensureWritableFilePath(options.profilePath, "profile");

    const Scene scene = loadScene(job.scenePath, job.sceneDefines);
    FilmSettings film = jobFilm(job, scene);
    const ExecutionPlan plan = planWithSceneHints(job, scene, film, registry);
    runPreflights(plan, scene, film);
    const PlannedPass& target = findInstance(plan, options.instance, job.path);
    const PassSpec& spec = target.registration->spec;
    std::map<std::string, BufferHandle> imported = loadInputs ? std::map<std::string, BufferHandle>{} : loadImports(plan);
    const jobs::ThreadLimit threadLimit(job.threads);
    const RayQuery rays(scene);

    ReplayResult result;
    result.instance = target.node.instance;
    result.pass = target.node.pass;
    result.threads = jobs::maxThreads();
    result.inputsLoaded = loadInputs;

    // The inputs, by version: shared read-only by every repetition; streamed
    // inputs as the batches the pipeline emitted, in order.
    std::map<std::string, BufferHandle> inputs;
    std::map<std::string, std::vector<std::pair<std::shared_ptr<void>, std::size_t>>> recordedBatches;
    std::vector<std::string> versions;
    for (const auto& [slot, inout] : readSlots(spec)) {
        const std::string& version = target.node.inputBindings.at(slot->name);
        if (!version.empty()) versions.push_back(version);
    }
    const std::int64_t inputs0 = jobs::wallNanos();
    if (loadInputs) {
        for (const auto& [slot, inout] : readSlots(spec)) {
            const std::string& version = target.node.inputBindings.at(slot->name);
            if (!version.empty())
                inputs[version] = loadBuffer(inputPath(options.inputsDirectory, version), slot->type, version);
        }
    } else if (options.saveInputsDirectory.empty() &&
               std::any_of(versions.begin(), versions.end(), [&](const std::string& v) { return plan.streamed(v); })) {
        // Streamed inputs are recorded batch by batch as the pipeline streams them
        // to the pass, so every repetition sees the batches of a full render: the
        // pass runs once inside the pipeline (its outputs are those of a render)
        // and its stored inputs are kept.
        std::vector<std::string> kept;
        for (const std::string& version : versions)
            if (!plan.streamed(version)) kept.push_back(version);
        for (const auto& [slot, version] : target.node.outputBindings) kept.push_back(version);
        const ExecutionPlan upstream = plan.producing(kept);
        for (const std::string& version : versions)
            if (plan.streamed(version) && !upstream.streamed(version))
                throw std::logic_error("replay: '" + version + "' is no longer streamed without the passes after '" +
                                       target.node.instance + "'");
        for (const PlannedPass& p : upstream.passes())
            result.passesRunForInputs += p.culled || p.node.instance == target.node.instance ? 0 : 1;
        RunOptions runOptions;
        runOptions.seed = job.seed;
        runOptions.film = film;
        runOptions.imported = imported;
        runOptions.save = [&inputs](const std::string& version, const std::string&, const BufferHandle& buffer) {
            inputs[version] = buffer;
        };
        runOptions.batchTap = [&](const std::string& version, const std::shared_ptr<void>& batch, std::size_t bytes) {
            if (std::find(versions.begin(), versions.end(), version) != versions.end())
                recordedBatches[version].push_back({batch, bytes});
        };
        execute(upstream, scene, rays, runOptions);
        for (const std::string& version : versions)
            if (!inputs.count(version) && imported.count(version)) inputs[version] = imported.at(version);
    } else {
        const ExecutionPlan upstream = plan.producing(versions);
        for (const PlannedPass& p : upstream.passes()) result.passesRunForInputs += p.culled ? 0 : 1;
        RunOptions runOptions;
        runOptions.seed = job.seed;
        runOptions.film = film;
        runOptions.imported = imported;
        runOptions.save = [&inputs](const std::string& version, const std::string&, const BufferHandle& buffer) {
            inputs[version] = buffer;
        };
        execute(upstream, scene, rays, runOptions);
        for (const std::string& version : versions)
            if (!inputs.count(version) && imported.count(version)) inputs[version] = imported.at(version);
    }
    result.inputsSeconds = 1e-9 * static_cast<double>(jobs::wallNanos() - inputs0);
    for (const auto& [slot, inout] : readSlots(spec)) {
        const std::string& version = target.node.inputBindings.at(slot->name);
        if (version.empty()) continue;
        if (const auto recorded = recordedBatches.find(version); recorded != recordedBatches.end()) {
            std::size_t bytes = 0;
            for (const auto& [batch, size] : recorded->second) bytes += size;
            result.inputs.push_back({slot->name, version, slot->type, bytes, recorded->second.size()});
            continue;
        }
        const BufferHandle& buffer = inputs.at(version);
        if (!buffer.data) throw std::logic_error("input '" + version + "' of '" + target.node.instance + "' was not made");
        result.inputs.push_back({slot->name, version, buffer.type, buffer.bytes ? buffer.bytes() : 0});
    }
    if (!options.saveInputsDirectory.empty()) {
        for (const ReplayInput& input : result.inputs) {
            const std::string path = inputPath(options.saveInputsDirectory, input.version);
            saveBuffer(inputs.at(input.version), path, job.text);
            result.files.push_back(path);
        }
    }
    // An in-out slot updates its input in place: each repetition starts from a
    // fresh copy, decoded from a file written once.
    std::optional<ScratchDirectory> scratch;
    std::map<std::string, std::string> inoutCopies;  // slot -> file
    for (const SlotSpec& io : spec.inouts) {
        if (!scratch) scratch.emplace();
        const std::string path = scratch->file(io.name + ".fgbuf");
        saveBuffer(inputs.at(target.node.inputBindings.at(io.name)), path, job.text);
        inoutCopies[io.name] = path;
    }

    auto& recorder = jobs::TraceRecorder::instance();
    recorder.setEnabled(!options.profilePath.empty());
    recorder.take();
    std::map<std::string, std::string> firstEncoding;  // slot -> encoded output of repetition 1
    for (int repetition = 1; repetition <= options.repeat; ++repetition) {
        std::map<std::string, BufferHandle> outputHandles;
        std::map<std::string, BufferHandle*> inputSlots, outputSlots;
        std::map<std::string, BufferHandle> standIns;  // streamed inputs: the batch being consumed
        for (const SlotSpec& in : spec.inputs) {
            const std::string& version = target.node.inputBindings.at(in.name);
            if (recordedBatches.count(version)) {
                standIns[in.name].type = in.type;
                inputSlots[in.name] = &standIns[in.name];
                continue;
            }
            inputSlots[in.name] = version.empty() ? nullptr : &inputs.at(version);
        }
        for (const SlotSpec& out : spec.outputs) {
            outputHandles[out.name].type = out.type;
            outputSlots[out.name] = &outputHandles[out.name];
        }
        for (const SlotSpec& io : spec.inouts) {
            outputHandles[io.name] = loadBuffer(inoutCopies.at(io.name), io.type);
            outputSlots[io.name] = &outputHandles[io.name];
        }
        const std::unique_ptr<Pass> pass = target.registration->create();
        PassContext context(scene, &rays, film, job.seed, target.params, inputSlots, outputSlots, target.node.instance);
        context.setIteration(target.iteration);
        context.setDeclaredSignals(spec.signals);
        PassTiming timing;
        timing.work.label = target.node.instance;
        const std::string label = target.node.instance + " #" + std::to_string(repetition);
        // As the scheduler does: streamed inputs batch by batch as they were emitted
        // (interleaved across slots in emission order is not kept: each slot's
        // batches in order), stored streamable inputs as one batch.
        for (const SlotSpec& in : spec.inputs) {
            const std::string& version = target.node.inputBindings.at(in.name);
            if (const auto recorded = recordedBatches.find(version); recorded != recordedBatches.end()) {
                for (const auto& [batch, size] : recorded->second) {
                    standIns.at(in.name).data = batch;
                    timePass(timing, label, [&] { pass->consumeBatch(context, in.name); });
                }
                standIns.at(in.name).data.reset();
            } else if (in.streamable && inputSlots.at(in.name)) {
                timePass(timing, label, [&] { pass->consumeBatch(context, in.name); });
            }
        }
        timePass(timing, label, [&] { pass->run(context); });

        ReplayRepetition& stats = result.repetitions.emplace_back();
        stats.wallSeconds = 1e-9 * static_cast<double>(timing.wallNs);
        stats.cpuSeconds = timing.cpuSeconds();
        stats.items = context.items();
        for (auto& [slot, handle] : outputHandles) {
            if (!handle.data)
                throw std::logic_error("pass '" + target.node.instance + "' did not produce its output '" + slot + "'");
            std::string encoded = comparableEncoding(handle);
            if (repetition == 1) {
                firstEncoding[slot] = std::move(encoded);
                result.outputs[slot] = handle;
                result.outputVersions[slot] = target.node.outputBindings.at(slot);
            } else if (encoded != firstEncoding.at(slot)) {
                result.differences.push_back(slot + " (repetition " + std::to_string(repetition) + ")");
            }
        }
    }
    recorder.setEnabled(false);
    if (!options.profilePath.empty()) {
        const std::string trace = chromeTraceJson(recorder.take());
        writeAtomically(options.profilePath, [&](const std::string& temporary) {
            writeFileChecked(options.profilePath, temporary, trace);
        });
        result.files.push_back(options.profilePath);
    }
    return result;
}

std::string formatReplayReport(const ReplayResult& result) {
    std::ostringstream out;
    out << "replay " << result.instance << " (pass " << result.pass << "), " << result.repetitions.size()
        << " repetitions, " << result.threads << " threads\n";
    out << std::fixed << std::setprecision(3);
    if (result.inputsLoaded) out << "inputs loaded from files in " << result.inputsSeconds << " s:";
    else out << "inputs made by " << result.passesRunForInputs << " passes in " << result.inputsSeconds << " s:";
    if (result.inputs.empty()) out << " none";
    for (std::size_t i = 0; i < result.inputs.size(); ++i) {
        const ReplayInput& input = result.inputs[i];
        out << (i ? "," : "") << ' ' << input.slot;
        if (input.version != input.slot) out << " = " << input.version;
        out << " (" << input.type << ", " << input.bytes << " bytes";
        if (input.batches > 0) out << " in " << input.batches << " streamed batches";
        out << ")";
    }
    out << '\n';
    out << std::left << std::setw(12) << "repetition" << std::right << std::setw(12) << "wall s" << std::setw(12)
        << "cpu s" << std::setw(8) << "cpu/w" << std::setw(14) << "items" << std::setw(16) << "items/s" << '\n';
    const auto row = [&](const std::string& name, double wall, double cpu, std::int64_t items, double rate) {
        out << std::left << std::setw(12) << name << std::right << std::setprecision(6) << std::setw(12) << wall
            << std::setw(12) << cpu << std::setprecision(2) << std::setw(8) << (wall > 0 ? cpu / wall : 0.0)
            << std::setw(14) << items << std::setprecision(0) << std::setw(16) << rate << '\n';
    };
    std::vector<double> walls, cpus, rates;
    for (std::size_t r = 0; r < result.repetitions.size(); ++r) {
        const ReplayRepetition& rep = result.repetitions[r];
        row(std::to_string(r + 1), rep.wallSeconds, rep.cpuSeconds, rep.items, rep.itemsPerSecond());
        walls.push_back(rep.wallSeconds);
        cpus.push_back(rep.cpuSeconds);
        rates.push_back(rep.itemsPerSecond());
    }
    const std::int64_t items = result.repetitions.empty() ? 0 : result.repetitions.front().items;
    row("median", median(walls), median(cpus), items, median(rates));
    std::string outputs;
    for (const auto& [slot, handle] : result.outputs) {
        outputs += (outputs.empty() ? "" : ", ") + slot;
        const std::string& version = result.outputVersions.at(slot);
        if (version != slot) outputs += " = " + version;
        outputs += " (" + handle.type + ")";
    }
    if (result.identical()) {
        out << "outputs identical in every repetition: " << (outputs.empty() ? "none" : outputs) << '\n';
    } else {
        std::string differing;
        for (const std::string& d : result.differences) differing += (differing.empty() ? "" : ", ") + d;
        out << "outputs DIFFER from repetition 1's: " << differing << '\n';
    }
    return out.str();
}

}  // namespace fg
