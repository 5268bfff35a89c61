#include <frostvdb/core/State.h>
#include <frostvdb/core/PlaneFold.h>
#include <frostvdb/core/Random.h>

#include <openvdb/io/Stream.h>

#include <algorithm>
#include <set>
#include <sstream>

namespace frostvdb {

namespace {

constexpr char kMagic[8] = {'F', 'R', 'O', 'S', 'T', 'C', 'K', 'P'};
constexpr uint32_t kVersion = 1;

template <typename T>
void putPod(std::string& out, T v)
{
    out.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

/// Reads from a byte string with bounds checks (a truncated file is an error, never a crash).
struct Cursor {
    const std::string& s;
    size_t pos;
    const std::string& label;
    template <typename T>
    T pod()
    {
        need(sizeof(T));
        T v;
        std::memcpy(&v, s.data() + pos, sizeof(T));
        pos += sizeof(T);
        return v;
    }
    std::string bytes(uint64_t n)
    {
        need(n);
        std::string b = s.substr(pos, size_t(n));
        pos += size_t(n);
        return b;
    }
    void need(uint64_t n) const
    {
        if (n > s.size() - pos) throw CheckpointError(label + ": truncated checkpoint");
    }
};

/// A 64-bit checksum of the payload, eight bytes at a time.
uint64_t checksum(const char* data, size_t n)
{
    uint64_t h = 0x243F6A8885A308D3ull ^ n;
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        uint64_t w;
        std::memcpy(&w, data + i, 8);
        h = mix64(h ^ w);
    }
    uint64_t tail = 0;
    std::memcpy(&tail, data + i, n - i);
    return mix64(h ^ tail ^ 0xA5);
}

} // namespace

void StateArchive::put(const std::string& key, Entry e) { mEntries[key] = std::move(e); }

const StateArchive::Entry& StateArchive::get(const std::string& key, Type type) const
{
    auto it = mEntries.find(key);
    if (it == mEntries.end()) throw CheckpointError("checkpoint has no value '" + key + "'");
    if (it->second.type != type) throw CheckpointError("checkpoint value '" + key + "' has another type");
    return it->second;
}

std::vector<std::string> StateArchive::keys(const std::string& prefix) const
{
    std::vector<std::string> k;
    for (auto it = mEntries.lower_bound(prefix); it != mEntries.end() && it->first.compare(0, prefix.size(), prefix) == 0;
         ++it)
        k.push_back(it->first);
    return k;
}

std::string StateArchive::serialise() const
{
    std::string payload;
    putPod<uint64_t>(payload, mEntries.size());
    for (const auto& [key, e] : mEntries) {
        putPod<uint32_t>(payload, uint32_t(key.size()));
        payload += key;
        putPod<uint8_t>(payload, uint8_t(e.type));
        putPod<uint32_t>(payload, e.elementSize);
        putPod<uint64_t>(payload, e.bytes.size());
        payload += e.bytes;
    }
    std::string out(kMagic, sizeof(kMagic));
    putPod<uint32_t>(out, kVersion);
    putPod<uint64_t>(out, payload.size());
    out += payload;
    putPod<uint64_t>(out, checksum(payload.data(), payload.size()));
    return out;
}

StateArchive StateArchive::deserialise(const std::string& s, const std::string& label)
{
    if (s.size() < sizeof(kMagic) + 12 || s.compare(0, sizeof(kMagic), kMagic, sizeof(kMagic)) != 0)
        throw CheckpointError(label + ": not a frostvdb checkpoint");
    Cursor c{s, sizeof(kMagic), label};
    const uint32_t version = c.pod<uint32_t>();
    if (version != kVersion)
        throw CheckpointError(label + ": checkpoint format " + std::to_string(version) + ", this frostvdb reads " +
                              std::to_string(kVersion));
    const uint64_t n = c.pod<uint64_t>();
    c.need(n);
    const size_t start = c.pos;
    Cursor tail{s, start + size_t(n), label};
    if (tail.pod<uint64_t>() != checksum(s.data() + start, size_t(n)))
        throw CheckpointError(label + ": checksum mismatch (the checkpoint is damaged)");
    StateArchive a;
    const uint64_t count = c.pod<uint64_t>();
    for (uint64_t i = 0; i < count; ++i) {
        const std::string key = c.bytes(c.pod<uint32_t>());
        Entry e;
        e.type = Type(c.pod<uint8_t>());
        e.elementSize = c.pod<uint32_t>();
        e.bytes = c.bytes(c.pod<uint64_t>());
        a.mEntries[key] = std::move(e);
    }
    return a;
}

void StateWriter::putInt(const std::string& key, int64_t v)
{
    StateArchive::Entry e;
    e.type = StateArchive::Type::Int;
    putPod(e.bytes, v);
    mArchive->put(mPrefix + key, std::move(e));
}

void StateWriter::putDouble(const std::string& key, double v)
{
    StateArchive::Entry e;
    e.type = StateArchive::Type::Double;
    putPod(e.bytes, v);
    mArchive->put(mPrefix + key, std::move(e));
}

void StateWriter::putString(const std::string& key, const std::string& v)
{
    StateArchive::Entry e;
    e.type = StateArchive::Type::String;
    e.bytes = v;
    mArchive->put(mPrefix + key, std::move(e));
}

void StateWriter::putBytes(const std::string& key, const void* data, size_t bytes, uint32_t elementSize)
{
    StateArchive::Entry e;
    e.type = StateArchive::Type::Array;
    e.elementSize = elementSize;
    if (bytes) e.bytes.assign(static_cast<const char*>(data), bytes);
    mArchive->put(mPrefix + key, std::move(e));
}

void StateWriter::putGrid(const std::string& key, const openvdb::GridBase::ConstPtr& grid)
{
    StateArchive::Entry e;
    e.type = StateArchive::Type::Grid;
    if (grid) {
        // The metadata names as they are now: the reader drops what the stream adds (file_*).
        std::vector<std::string> names;
        for (auto it = grid->beginMeta(); it != grid->endMeta(); ++it) names.push_back(it->first);
        putPod<uint32_t>(e.bytes, uint32_t(names.size()));
        for (auto& n : names) {
            putPod<uint32_t>(e.bytes, uint32_t(n.size()));
            e.bytes += n;
        }
        // a shallow copy (tree shared, metadata copied): the half-float flag is set on the copy only
        openvdb::GridBase::Ptr copy = openvdb::ConstPtrCast<openvdb::GridBase>(grid)->copyGrid();
        copy->setSaveFloatAsHalf(false);
        std::ostringstream os(std::ios::binary);
        openvdb::io::Stream stream(os);
        // Exact bits: no half floats, no active-mask compression (it folds -0 into +0 backgrounds).
        stream.setCompression(openvdb::io::Archive::hasBloscCompression() ? openvdb::io::COMPRESS_BLOSC
                                                                          : openvdb::io::COMPRESS_ZIP);
        stream.write(openvdb::GridCPtrVec{copy});
        e.bytes += os.str();
    }
    mArchive->put(mPrefix + key, std::move(e));
}

int64_t StateReader::getInt(const std::string& key) const
{
    const auto& b = mArchive->get(mPrefix + key, StateArchive::Type::Int).bytes;
    if (b.size() != 8) fail(key, "damaged integer");
    int64_t v;
    std::memcpy(&v, b.data(), 8);
    return v;
}

double StateReader::getDouble(const std::string& key) const
{
    const auto& b = mArchive->get(mPrefix + key, StateArchive::Type::Double).bytes;
    if (b.size() != 8) fail(key, "damaged number");
    double v;
    std::memcpy(&v, b.data(), 8);
    return v;
}

std::string StateReader::getString(const std::string& key) const
{
    return mArchive->get(mPrefix + key, StateArchive::Type::String).bytes;
}

const std::string& StateReader::bytes(const std::string& key, uint32_t elementSize) const
{
    const auto& e = mArchive->get(mPrefix + key, StateArchive::Type::Array);
    if (e.elementSize != elementSize || e.bytes.size() % elementSize != 0)
        fail(key, "array of " + std::to_string(e.elementSize) + "-byte values, expected " + std::to_string(elementSize));
    return e.bytes;
}

openvdb::GridBase::Ptr StateReader::getGridBase(const std::string& key) const
{
    const auto& b = mArchive->get(mPrefix + key, StateArchive::Type::Grid).bytes;
    if (b.empty()) return nullptr;
    Cursor c{b, 0, mLabel};
    std::set<std::string> names;
    const uint32_t n = c.pod<uint32_t>();
    for (uint32_t i = 0; i < n; ++i) names.insert(c.bytes(c.pod<uint32_t>()));
    std::istringstream is(b.substr(c.pos), std::ios::binary);
    openvdb::GridPtrVecPtr grids;
    try {
        openvdb::io::Stream stream(is, /*delayLoad=*/false);
        grids = stream.getGrids();
    } catch (const std::exception& e) {
        fail(key, std::string("cannot read grid: ") + e.what());
    }
    if (!grids || grids->size() != 1) fail(key, "expected one grid");
    openvdb::GridBase::Ptr g = grids->front();
    std::vector<std::string> extra;
    for (auto it = g->beginMeta(); it != g->endMeta(); ++it)
        if (!names.count(it->first)) extra.push_back(it->first);
    for (auto& k : extra) g->removeMeta(k);
    plane::upgradeLegacyFold(*g); // a checkpoint written with the first plane fold
    return g;
}

std::vector<std::string> StateReader::keys() const
{
    std::vector<std::string> k = mArchive->keys(mPrefix);
    for (auto& s : k) s = s.substr(mPrefix.size());
    return k;
}

void StateReader::fail(const std::string& key, const std::string& what) const
{
    throw CheckpointError(mLabel + ": " + mPrefix + key + ": " + what);
}

} // namespace frostvdb
