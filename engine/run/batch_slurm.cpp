// The cluster side of batches: the sbatch script of a plan's job array and the
// merge of the tasks' tables into the plan's results table. Task tables are
// only ever appended to (a rerun task adds rows), so merging picks, for every
// run, the row of the latest invocation and leaves the task files untouched:
// collecting again later, after more tasks finished, gives the full table.
#include "engine/run/batch_slurm.h"

#include "engine/core/error.h"
#include "engine/core/output_files.h"
#include "engine/run/batch.h"

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <tuple>

namespace fg {

namespace {

namespace fs = std::filesystem;

std::string shellQuote(const std::string& word) {
    std::string quoted = "'";
    for (char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return quoted + "'";
}

std::string readWholeFile(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::stringstream buffer;
    buffer << in.rdbuf();
    return buffer.str();
}

// CSV records (a quoted field may hold a newline), each with its fields unquoted
// and its original text, newline included, for writing back unchanged.
struct CsvRecord {
    std::vector<std::string> fields;
    std::string text;
};

std::vector<CsvRecord> csvRecords(const std::string& text) {
    std::vector<CsvRecord> records;
    CsvRecord record;
    std::string field;
    bool quoted = false;
    std::size_t start = 0;
    for (std::size_t i = 0; i < text.size(); ++i) {
        const char c = text[i];
        if (quoted) {
            if (c == '"' && i + 1 < text.size() && text[i + 1] == '"') {
                field += '"';
                ++i;
            } else if (c == '"') {
                quoted = false;
            } else {
                field += c;
            }
        } else if (c == '"') {
            quoted = true;
        } else if (c == ',') {
            record.fields.push_back(std::move(field));
            field.clear();
        } else if (c == '\n') {
            record.fields.push_back(std::move(field));
            field.clear();
            record.text = text.substr(start, i + 1 - start);
            records.push_back(std::move(record));
            record = CsvRecord{};
            start = i + 1;
        } else if (c != '\r') {
            field += c;
        }
    }
    // A last line without its newline is a row still being written: left out.
    return records;
}

// The value of the JSON string that follows `"key": ` first in the line.
std::optional<std::string> jsonStringField(const std::string& line, const std::string& key) {
    const std::string marker = "\"" + key + "\": \"";
    std::size_t i = line.find(marker);
    if (i == std::string::npos) return std::nullopt;
    std::string value;
    for (i += marker.size(); i < line.size(); ++i) {
        const char c = line[i];
        if (c == '"') return value;
        if (c != '\\' || i + 1 >= line.size()) {
            value += c;
            continue;
        }
        const char escaped = line[++i];
        switch (escaped) {
        case 'n': value += '\n'; break;
        case 't': value += '\t'; break;
        case 'u':
            if (i + 4 < line.size()) value += static_cast<char>(std::stoi(line.substr(i + 1, 4), nullptr, 16));
            i += 4;
            break;
        default: value += escaped;
        }
    }
    return std::nullopt;
}

// Orders rows of one run from different invocations: the invocation's start,
// then the file written last, then the later line.
using RowAge = std::tuple<std::string, std::int64_t, std::size_t>;

struct LatestRow {
    RowAge age;
    std::string text;
    std::string status;
};

std::int64_t modificationTicks(const fs::path& path) {
    std::error_code ec;
    const auto time = fs::last_write_time(path, ec);
    return ec ? 0 : static_cast<std::int64_t>(time.time_since_epoch().count());
}

void keepLatest(std::map<std::string, LatestRow>& rows, const std::string& run, LatestRow row) {
    auto it = rows.find(run);
    if (it == rows.end()) rows.emplace(run, std::move(row));
    else if (it->second.age < row.age) it->second = std::move(row);
}

// Every task table with the given extension, e.g. ".csv".
std::vector<fs::path> taskTables(const BatchPlan& plan, const std::string& extension) {
    std::vector<fs::path> tables;
    const fs::path directory = fs::path(plan.outputDirectory) / kBatchTaskDirectory;
    std::error_code ec;
    if (!fs::is_directory(directory, ec)) return tables;
    for (const auto& entry : fs::directory_iterator(directory, ec)) {
        const std::string name = entry.path().filename().string();
        if (name.rfind("task-", 0) == 0 && entry.path().extension() == extension) tables.push_back(entry.path());
    }
    std::sort(tables.begin(), tables.end());
    return tables;
}

// Written next to the target, then renamed over it: a reader never sees half a table.
void replaceFile(const fs::path& path, const std::string& text) {
    std::string hiddenName = path.filename().string();
    hiddenName.insert(0, 1, '.');  // not "." + name: GCC 12 warns (-Wrestrict, falsely) on that
    const fs::path temporary = path.parent_path() / (hiddenName + ".collecting");
    writeFileChecked(path.string(), temporary.string(), text);
    std::error_code ec;
    fs::rename(temporary, path, ec);
    if (ec) throw InputError(path.string() + ": cannot replace: " + ec.message());
}

}  // namespace

std::size_t batchTaskCount(std::size_t runCount, std::size_t runsPerTask) {
    if (runsPerTask == 0) return 0;
    return (runCount + runsPerTask - 1) / runsPerTask;
}

std::string batchTaskTableBase(const BatchPlan& plan, std::size_t task) {
    return (fs::path(plan.outputDirectory) / kBatchTaskDirectory / ("task-" + std::to_string(task))).string();
}

std::string slurmArrayScript(const BatchPlan& plan, const SlurmScriptOptions& options) {
    const std::size_t tasks = batchTaskCount(plan.runs.size(), options.runsPerTask);
    const fs::path output = fs::path(options.workingDirectory) / plan.outputDirectory;
    const fs::path logs = (output / kBatchTaskDirectory).lexically_normal();
    std::ostringstream script;
    script << "#!/bin/bash\n"
           << "# fluxgraph batch on SLURM: " << plan.runs.size() << " runs of " << options.planPath << " in " << tasks
           << " array task" << (tasks == 1 ? "" : "s") << " of up to " << options.runsPerTask << " run"
           << (options.runsPerTask == 1 ? "" : "s") << ".\n"
           << "# Each task appends its rows to " << (logs / "task-<index>.csv").string() << "; merge them with\n"
           << "#   " << shellQuote(options.binary) << " batch " << shellQuote(options.planPath) << " --collect\n"
           << "#SBATCH --job-name=fluxgraph-" << fs::path(options.planPath).stem().string() << "\n"
           << "#SBATCH --array=0-" << (tasks == 0 ? 0 : tasks - 1) << "\n"
           << "#SBATCH --chdir=" << options.workingDirectory << "\n"
           << "#SBATCH --output=" << (logs / "task-%a.log").string() << "\n";
    if (!options.partition.empty()) script << "#SBATCH --partition=" << options.partition << "\n";
    if (!options.timeLimit.empty()) script << "#SBATCH --time=" << options.timeLimit << "\n";
    script << "cd " << shellQuote(options.workingDirectory) << " || exit 1\n"
           << "exec " << shellQuote(options.binary) << " batch " << shellQuote(options.planPath)
           << " --task \"$SLURM_ARRAY_TASK_ID\" --runs-per-task " << options.runsPerTask;
    for (const std::string& argument : options.taskArguments) script << " " << shellQuote(argument);
    script << "\n";
    return script.str();
}

std::string writeSlurmArrayScript(const BatchPlan& plan, const SlurmScriptOptions& options) {
    const fs::path output = fs::path(options.workingDirectory) / plan.outputDirectory;
    std::error_code ec;
    fs::create_directories(output / kBatchTaskDirectory, ec);
    if (ec) throw InputError((output / kBatchTaskDirectory).string() + ": cannot create: " + ec.message());
    const fs::path script = (output / kBatchScriptName).lexically_normal();
    replaceFile(script, slurmArrayScript(plan, options));
    fs::permissions(script, fs::perms::owner_exec | fs::perms::group_exec, fs::perm_options::add, ec);
    return script.string();
}

BatchCollection collectBatchTasks(const BatchPlan& plan) {
    std::map<std::string, LatestRow> csvRows;
    std::map<std::string, LatestRow> jsonRows;
    const std::vector<std::string>& columns = batchCsvColumns();
    const auto column = [&](const std::string& name) {
        return static_cast<std::size_t>(std::find(columns.begin(), columns.end(), name) - columns.begin());
    };
    const std::size_t startedColumn = column("batch_started");
    const std::size_t runColumn = column("run");
    const std::size_t statusColumn = column("status");

    for (const fs::path& table : taskTables(plan, ".csv")) {
        const std::int64_t ticks = modificationTicks(table);
        const std::vector<CsvRecord> records = csvRecords(readWholeFile(table));
        for (std::size_t line = 0; line < records.size(); ++line) {
            const CsvRecord& record = records[line];
            if (record.fields.size() != columns.size() || record.fields == columns) continue;
            keepLatest(csvRows, record.fields[runColumn],
                       LatestRow{{record.fields[startedColumn], ticks, line}, record.text, record.fields[statusColumn]});
        }
    }
    for (const fs::path& table : taskTables(plan, ".jsonl")) {
        const std::int64_t ticks = modificationTicks(table);
        std::istringstream in(readWholeFile(table));
        std::size_t line = 0;
        for (std::string text; std::getline(in, text); ++line) {
            if (in.eof()) break;  // no newline yet: a row still being written
            const auto started = jsonStringField(text, "batch_started");
            const auto run = jsonStringField(text, "run");
            if (!started || !run) continue;
            keepLatest(jsonRows, *run, LatestRow{{*started, ticks, line}, text + "\n", {}});
        }
    }

    BatchCollection collection;
    collection.runs = plan.runs.size();
    std::string csv;
    for (const std::string& name : columns) csv += (csv.empty() ? "" : ",") + name;
    csv += "\n";
    std::string jsonl;
    for (const BatchRun& run : plan.runs) {
        const auto row = csvRows.find(run.name);
        if (row != csvRows.end()) {
            csv += row->second.text;
            if (row->second.status == "failed") ++collection.failed;
        }
        if (const auto json = jsonRows.find(run.name); json != jsonRows.end()) jsonl += json->second.text;
        const bool finished = row != csvRows.end() && (row->second.status == "ok" || row->second.status == "skipped");
        if (finished) ++collection.finished;
        else collection.missing.push_back(run.name);
    }
    std::error_code ec;
    fs::create_directories(plan.outputDirectory, ec);
    replaceFile(fs::path(plan.outputDirectory) / kBatchCsvName, csv);
    replaceFile(fs::path(plan.outputDirectory) / kBatchJsonlName, jsonl);
    return collection;
}

}  // namespace fg
