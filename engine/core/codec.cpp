// Buffer files: the header, the bounds checks that keep a corrupt or hostile
// file from making the reader allocate or read past its end, the codec table
// and atomic saving. The layout is described in codec.h.
#include "engine/core/codec.h"

#include "engine/core/output_files.h"

#include <algorithm>
#include <cerrno>
#include <filesystem>
#include <limits>
#include <map>
#include <mutex>
#include <ostream>
#include <stdexcept>
#include <system_error>

namespace fg {

namespace {

// Limits on header strings shown in messages, so that garbage that happens to
// start like a buffer file cannot turn a one-line error into a page.
constexpr std::uint64_t kMaxTypeNameLength = 128;
constexpr std::uint64_t kMaxColumnNameLength = 256;
// The smallest column descriptor: empty name (u32), element size, count.
constexpr std::uint64_t kMinColumnDescriptorBytes = 4 + 4 + 8;

// Names are printed in one-line messages: printable ASCII only.
bool isPrintableName(std::string_view name, bool allowSpaces) {
    if (name.empty()) return false;
    return std::all_of(name.begin(), name.end(), [allowSpaces](char c) {
        return (c > ' ' && c < 0x7f) || (allowSpaces && c == ' ');
    });
}

std::string article(const std::string& noun) {
    return !noun.empty() && std::string_view("AEIOUaeiou").find(noun.front()) != std::string_view::npos ? "an "
                                                                                                        : "a ";
}

void put(std::ostream& out, const void* bytes, std::size_t size) {
    out.write(static_cast<const char*>(bytes), static_cast<std::streamsize>(size));
}
template <class T>
void putScalar(std::ostream& out, T value) {
    put(out, &value, sizeof(T));
}
void putString(std::ostream& out, std::string_view text) {
    putScalar(out, static_cast<std::uint32_t>(text.size()));
    put(out, text.data(), text.size());
}

std::mutex& tableMutex() {
    static std::mutex mutex;
    return mutex;
}
std::map<std::string, BufferCodec>& table() {
    static std::map<std::string, BufferCodec> codecs;
    return codecs;
}
void addCodec(BufferCodec codec) {
    if (codec.type.empty() || !codec.write || !codec.read)
        throw std::invalid_argument("registerCodec: a codec needs a type, a write and a read function");
    const std::lock_guard lock(tableMutex());
    std::string type = codec.type;
    table()[std::move(type)] = std::move(codec);
}

}  // namespace

// --- CodecWriter -------------------------------------------------------------

void CodecWriter::writeString(std::string_view text) {
    if (text.size() > std::numeric_limits<std::uint32_t>::max())
        throw std::length_error("CodecWriter: string longer than 4 GiB");
    write(static_cast<std::uint32_t>(text.size()));
    appendOwned(text.data(), text.size());
}

void CodecWriter::appendOwned(const void* bytes, std::size_t size) {
    if (pieces_.empty() || pieces_.back().borrowed) pieces_.emplace_back();
    const char* begin = static_cast<const char*>(bytes);
    pieces_.back().owned.insert(pieces_.back().owned.end(), begin, begin + size);
}

void CodecWriter::addColumn(const std::string& name, std::size_t elementSize, std::size_t count, const void* data) {
    if (!isPrintableName(name, true) || name.size() > kMaxColumnNameLength)
        throw std::invalid_argument("CodecWriter: column name '" + name + "' is empty, too long or not printable");
    columns_.push_back(CodecColumn{name, static_cast<std::uint32_t>(elementSize), count});
    if (count == 0) return;
    Piece piece;
    piece.borrowed = data;
    piece.borrowedBytes = elementSize * count;
    pieces_.push_back(std::move(piece));
}

std::uint64_t CodecWriter::scalarBytes() const {
    std::uint64_t bytes = 0;
    for (const Piece& piece : pieces_) bytes += piece.owned.size();
    return bytes;
}

bool CodecWriter::writePayload(std::ostream& out) const {
    for (const Piece& piece : pieces_) {
        if (piece.borrowed)
            put(out, piece.borrowed, piece.borrowedBytes);
        else
            put(out, piece.owned.data(), piece.owned.size());
    }
    return static_cast<bool>(out);
}

// --- CodecReader -------------------------------------------------------------

CodecReader::CodecReader(const std::string& path) : path_(path) {
    std::error_code error;
    const auto status = std::filesystem::status(path, error);
    if (error || !std::filesystem::exists(status))
        fail("cannot open buffer file: " + (error ? error.message() : std::string("no such file")));
    if (std::filesystem::is_directory(status)) fail("is a directory, not a buffer file");
    in_.open(path, std::ios::binary);
    if (!in_) fail("cannot open buffer file: " + std::generic_category().message(errno));
    const std::uint64_t size = std::filesystem::file_size(path, error);
    if (error) fail("cannot read buffer file: " + error.message());
    remaining_ = size;

    if (remaining_ == 0) fail("empty file, not a fluxgraph buffer file");
    char magic[sizeof kBufferFileMagic];
    const std::size_t magicBytes = static_cast<std::size_t>(std::min<std::uint64_t>(remaining_, sizeof magic));
    readBytes(magic, magicBytes);
    if (std::memcmp(magic, kBufferFileMagic, magicBytes) != 0) fail("not a fluxgraph buffer file");
    if (magicBytes < sizeof magic) fail("truncated buffer file");

    const auto version = read<std::uint32_t>();
    if (version != kBufferFormatVersion)
        fail("buffer file format version " + std::to_string(version) + " is not supported (this build reads version " +
             std::to_string(kBufferFormatVersion) + ")");

    type_ = readHeaderString("type name", kMaxTypeNameLength);
    if (!isPrintableName(type_, false)) fail("corrupt header: the type name is not printable");

    const auto columnCount = read<std::uint32_t>();
    if (columnCount > remaining_ / kMinColumnDescriptorBytes)
        fail("truncated buffer file: " + std::to_string(columnCount) + " columns do not fit in it");
    columns_.reserve(columnCount);
    for (std::uint32_t i = 0; i < columnCount; ++i) {
        CodecColumn column;
        column.name = readHeaderString("column name", kMaxColumnNameLength);
        if (!isPrintableName(column.name, true)) fail("corrupt header: a column name is not printable");
        column.elementSize = read<std::uint32_t>();
        column.count = read<std::uint64_t>();
        if (column.elementSize == 0) fail("corrupt header: column '" + column.name + "' has 0-byte elements");
        columns_.push_back(std::move(column));
    }
    items_ = read<std::uint64_t>();
    jobText_ = readHeaderString("job text", remaining_);

    // Every column's bytes must be in the file, so that no count read from it
    // can make the reader allocate more than the file holds.
    std::uint64_t columnBytes = 0;
    for (const CodecColumn& column : columns_) {
        const std::uint64_t room = remaining_ - columnBytes;
        if (column.count > room / column.elementSize)
            fail("truncated buffer file: column '" + column.name + "' needs more bytes than the file has left");
        columnBytes += column.count * column.elementSize;
    }
    columnBytes_ = columnBytes;
}

void CodecReader::fail(const std::string& message) const { throw InputError(path_, 0, message); }

void CodecReader::readBytes(void* out, std::uint64_t size) {
    if (size > remaining_) fail("truncated buffer file");
    if (size == 0) return;
    in_.read(static_cast<char*>(out), static_cast<std::streamsize>(size));
    if (!in_) fail("truncated buffer file (could not read " + std::to_string(size) + " bytes)");
    remaining_ -= size;
}

std::string CodecReader::readHeaderString(const char* what, std::uint64_t maxLength) {
    const auto length = read<std::uint32_t>();
    if (length > remaining_) fail("truncated buffer file");
    if (length > maxLength) fail(std::string("corrupt header: ") + what + " of " + std::to_string(length) + " bytes");
    std::string text(length, '\0');
    readBytes(text.data(), length);
    return text;
}

std::string CodecReader::readString() {
    const auto length = read<std::uint32_t>();
    if (length > remaining_) fail("truncated buffer file");
    std::string text(length, '\0');
    readBytes(text.data(), length);
    return text;
}

const CodecColumn& CodecReader::expectColumn(std::string_view name, std::size_t elementSize) {
    if (nextColumn_ >= columns_.size())
        fail(article(type_) + type_ + " buffer needs column '" + std::string(name) +
             "', but the file lists no more columns");
    const CodecColumn& column = columns_[nextColumn_];
    if (column.name != name || column.elementSize != elementSize)
        fail("column " + std::to_string(nextColumn_ + 1) + " is '" + column.name + "' of " +
             std::to_string(column.elementSize) + "-byte elements, but " + article(type_) + type_ +
             " buffer stores '" + std::string(name) + "' of " + std::to_string(elementSize) + "-byte elements there");
    ++nextColumn_;
    return column;
}

void CodecReader::checkSoaColumn(std::size_t index, const std::string& name, std::size_t elementSize,
                                 std::uint64_t& count, bool& counted) const {
    if (index >= columns_.size())
        fail(article(type_) + type_ + " buffer needs column '" + name + "', but the file lists no more columns");
    const CodecColumn& column = columns_[index];
    if (column.name != name || column.elementSize != elementSize)
        fail("column " + std::to_string(index + 1) + " is '" + column.name + "' of " +
             std::to_string(column.elementSize) + "-byte elements, but " + article(type_) + type_ +
             " buffer stores '" + name + "' of " + std::to_string(elementSize) + "-byte elements there");
    if (counted && column.count != count)
        fail("column '" + name + "' holds " + std::to_string(column.count) + " elements, the columns before it " +
             std::to_string(count));
    count = column.count;
    counted = true;
}

void CodecReader::readColumnBytes(void* out, const CodecColumn& column) {
    readBytes(out, column.count * column.elementSize);
}

void CodecReader::finish() {
    if (nextColumn_ < columns_.size())
        fail("column '" + columns_[nextColumn_].name + "' is not part of " + article(type_) + type_ + " buffer");
    if (remaining_ != 0) fail(std::to_string(remaining_) + " bytes after the end of the buffer");
}

// --- Codec table ---------------------------------------------------------------

void registerBuiltinCodecs() {
    static std::once_flag once;
    std::call_once(once, [] {
        for (BufferCodec& codec : builtinCodecs()) addCodec(std::move(codec));
    });
}

void registerCodec(BufferCodec codec) {
    // Builtins first, so that a codec registered here replaces a builtin one
    // instead of being replaced by it on the first lookup.
    registerBuiltinCodecs();
    addCodec(std::move(codec));
}

const BufferCodec* findCodec(const std::string& type) {
    registerBuiltinCodecs();
    const std::lock_guard lock(tableMutex());
    const auto it = table().find(type);
    return it == table().end() ? nullptr : &it->second;
}

std::vector<std::string> codecTypes() {
    registerBuiltinCodecs();
    const std::lock_guard lock(tableMutex());
    std::vector<std::string> types;
    for (const auto& [type, codec] : table()) types.push_back(type);
    return types;
}

// --- Files -------------------------------------------------------------------

void writeBufferFile(const BufferHandle& buffer, const std::string& path, const std::string& temporaryPath,
                     const std::string& jobText) {
    const BufferCodec* codec = findCodec(buffer.type);
    if (!codec)
        throw InputError(path, 0,
                         "cannot save " + article(buffer.type) + buffer.type + " buffer: no codec for that type");
    if (!buffer.data)
        throw InputError(path, 0,
                         "the " + buffer.type + " buffer holds no data (a streamed buffer is never stored whole)");
    if (jobText.size() > std::numeric_limits<std::uint32_t>::max())
        throw InputError(path, 0, "job text longer than 4 GiB");

    CodecWriter writer;
    codec->write(buffer.data.get(), writer);
    // A codec whose declared size is wrong would have validate refuse every
    // file it writes: found on the first save, not by its users.
    if (codec->scalarBytes && codec->scalarBytes(writer.columns()) != writer.scalarBytes())
        throw std::logic_error("the " + buffer.type + " codec wrote " + std::to_string(writer.scalarBytes()) +
                               " bytes besides its columns, but its scalarBytes says " +
                               std::to_string(codec->scalarBytes(writer.columns())));
    writeFileChecked(path, temporaryPath, [&](std::ostream& out) {
        put(out, kBufferFileMagic, sizeof kBufferFileMagic);
        putScalar(out, kBufferFormatVersion);
        putString(out, buffer.type);
        putScalar(out, static_cast<std::uint32_t>(writer.columns().size()));
        for (const CodecColumn& column : writer.columns()) {
            putString(out, column.name);
            putScalar(out, column.elementSize);
            putScalar(out, column.count);
        }
        putScalar(out, writer.itemCount());
        putString(out, jobText);
        writer.writePayload(out);
    });
}

void saveBuffer(const BufferHandle& buffer, const std::string& path, const std::string& jobText) {
    writeAtomically(path, [&](const std::string& temporary) { writeBufferFile(buffer, path, temporary, jobText); });
}

std::function<void(CodecReader&)> codecVersionCheck(std::uint32_t supported, std::string what) {
    return [supported, what = std::move(what)](CodecReader& reader) {
        const auto version = reader.read<std::uint32_t>();
        if (version != supported)
            reader.fail(what + " of codec version " + std::to_string(version) + " (this build reads version " +
                        std::to_string(supported) + ")");
    };
}

BufferCodec withScalarBytes(BufferCodec codec, std::uint64_t bytes) {
    codec.scalarBytes = [bytes](std::span<const CodecColumn>) { return bytes; };
    return codec;
}

namespace {

// Everything loadBuffer checks before the codec's read; leaves `reader` at the
// first payload byte after the codec's version.
const BufferCodec& checkedCodec(CodecReader& reader, const std::string& expectedType, const std::string& bufferName) {
    const std::string& type = reader.type();
    if (!expectedType.empty() && type != expectedType)
        reader.fail("holds " + article(type) + type + " buffer, but " +
                    (bufferName.empty() ? article(expectedType) + expectedType + " buffer is expected"
                                        : "'" + bufferName + "' is " + article(expectedType) + expectedType));
    const BufferCodec* codec = findCodec(type);
    if (!codec) reader.fail("holds " + article(type) + type + " buffer, which this build cannot read");
    const std::uint64_t payload = reader.remaining();
    // The version first: another version may have another size.
    if (codec->checkVersion) codec->checkVersion(reader);
    if (codec->scalarBytes) {
        // Both terms are bounded: the reader checked that the columns fit in
        // the file, and scalars come from the header's (bounded) names.
        const std::uint64_t expected = reader.columnBytes() + codec->scalarBytes(reader.columns());
        if (payload < expected)
            reader.fail("truncated buffer file: its header's columns need " + std::to_string(expected) +
                        " bytes after the header, the file has " + std::to_string(payload));
        if (payload > expected) reader.fail(std::to_string(payload - expected) + " bytes after the end of the buffer");
    }
    return *codec;
}

}  // namespace

void checkBufferFile(const std::string& path, const std::string& expectedType, const std::string& bufferName) {
    CodecReader reader(path);
    checkedCodec(reader, expectedType, bufferName);
}

BufferHandle loadBuffer(const std::string& path, const std::string& expectedType, const std::string& bufferName) {
    CodecReader reader(path);
    const BufferCodec& codec = checkedCodec(reader, expectedType, bufferName);
    const std::string& type = reader.type();
    BufferHandle handle;
    try {
        handle = codec.read(reader);
    } catch (const std::invalid_argument& error) {
        // The buffer types' own checks (Film::restore, KdTree::restore, ...) on
        // arrays that are complete but do not fit together.
        reader.fail(std::string("corrupt buffer: ") + error.what());
    } catch (const std::length_error& error) {
        reader.fail(std::string("corrupt buffer: ") + error.what());
    }
    reader.finish();
    if (handle.type != type || !handle.data || !handle.bytes)
        throw std::logic_error("the " + type + " codec returned an incomplete buffer handle");
    return handle;
}

BufferFileInfo readBufferInfo(const std::string& path) {
    const CodecReader reader(path);
    BufferFileInfo info;
    info.type = reader.type();
    info.jobText = reader.jobText();
    info.items = reader.itemCount();
    for (const CodecColumn& column : reader.columns()) info.columns.push_back(column.name);
    return info;
}

}  // namespace fg
