#include "server/store/instance_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <chrono>
#include <random>
#include <thread>

namespace fringe {

namespace fs = std::filesystem;

namespace {

bool valid_instance(const std::string& id) {
    if (id.empty() || id.size() > 64) return false;
    for (char c : id)
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_')) return false;
    return true;
}

std::string lock_dir(const std::string& data_dir) { return (fs::path(data_dir) / "locks").string(); }

// Opens (creating, mode 0600) and flocks path; -1 with errno EWOULDBLOCK if held elsewhere.
int open_locked(const std::string& path, int how) {
    const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0) return -1;
    if (::flock(fd, how | LOCK_NB) != 0) {
        const int e = errno;
        ::close(fd);
        errno = e;
        return -1;
    }
    return fd;
}

// The open descriptor fd is the file now named path (not one unlinked since it was opened).
bool same_file(int fd, const std::string& path) {
    struct stat a {}, b {};
    return ::fstat(fd, &a) == 0 && ::stat(path.c_str(), &b) == 0 && a.st_dev == b.st_dev && a.st_ino == b.st_ino;
}

void write_owner(int fd, const std::string& id) {
    const std::string text = "pid " + std::to_string(getpid()) + " instance " + id + "\n";
    if (::ftruncate(fd, 0) == 0) {
        [[maybe_unused]] const auto n = ::pwrite(fd, text.data(), text.size(), 0);
    }
}

}  // namespace

std::string new_instance_id() {
    std::random_device rd;
    char hex[17];
    std::snprintf(hex, sizeof hex, "%08x%08x", static_cast<unsigned>(rd()), static_cast<unsigned>(rd()));
    return hex;
}

InstanceLock::~InstanceLock() {
    if (instance_fd_ >= 0) {
        // Unlinked while still held: a prober that opens it now creates a fresh, unlocked file
        // and takes the run for dead, which it is about to be anyway (rows are finished first).
        std::error_code ec;
        fs::remove(instance_path_, ec);
        ::close(instance_fd_);
    }
    if (service_fd_ >= 0) ::close(service_fd_);
}

void InstanceLock::acquire_service(const std::string& data_dir, const std::string& instance_id) {
    fs::create_directories(data_dir);
    const std::string path = (fs::path(data_dir) / "lock").string();
    const int fd = open_locked(path, LOCK_EX);
    if (fd < 0) {
        if (errno != EWOULDBLOCK) throw std::runtime_error("cannot lock " + path + ": " + std::strerror(errno));
        std::string owner;
        if (FILE* f = std::fopen(path.c_str(), "r")) {
            char line[256] = {};
            if (std::fgets(line, sizeof line, f)) owner = line;
            std::fclose(f);
        }
        while (!owner.empty() && (owner.back() == '\n' || owner.back() == '\r')) owner.pop_back();
        throw InstanceLockBusy("data folder " + fs::absolute(data_dir).lexically_normal().string() + " is in use by another fringe serve (" +
                               (owner.empty() ? "holder unknown" : owner) + "); one service per data folder: stop it or give another --data");
    }
    write_owner(fd, instance_id);
    service_fd_ = fd;
    acquire_instance(data_dir, instance_id);
}

void InstanceLock::acquire_instance(const std::string& data_dir, const std::string& instance_id) {
    if (!valid_instance(instance_id)) throw std::runtime_error("bad instance id '" + instance_id + "'");
    fs::create_directories(lock_dir(data_dir));
    ::chmod(lock_dir(data_dir).c_str(), 0700);
    instance_path_ = (fs::path(lock_dir(data_dir)) / (instance_id + ".lock")).string();
    int fd = -1;
    // Another process may remove a lock file it found unheld between our open() and flock():
    // ours would then lock a file no longer in the folder, and a prober would find the name
    // gone and take our rows for dead. Holding the lock, check that the name is still our file.
    for (int attempt = 0; attempt < 100; ++attempt) {
        fd = open_locked(instance_path_, LOCK_EX);
        if (fd < 0 && errno == EWOULDBLOCK) {  // a prober holds it for an instant (the id is new: no owner)
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
            continue;
        }
        if (fd < 0) throw std::runtime_error("cannot lock " + instance_path_ + ": " + std::strerror(errno));
        if (same_file(fd, instance_path_)) break;
        ::close(fd);
        fd = -1;
    }
    if (fd < 0) throw std::runtime_error("cannot lock " + instance_path_ + ": it kept being held or removed by other processes");
    write_owner(fd, instance_id);
    instance_fd_ = fd;
    id_ = instance_id;
}

bool instance_alive(const std::string& data_dir, const std::string& instance_id) {
    if (!valid_instance(instance_id)) return false;
    const std::string path = (fs::path(lock_dir(data_dir)) / (instance_id + ".lock")).string();
    // Dead only when we know it: the file is gone, or we could lock it. Anything else (no
    // descriptors left, EACCES) says alive, since "dead" is written to the store for good.
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return errno != ENOENT;  // ENOENT: never made, or removed by its owner at exit
    const bool locked_by_us = ::flock(fd, LOCK_SH | LOCK_NB) == 0;
    const bool held = !locked_by_us;  // EWOULDBLOCK: someone holds it; other errors: cannot tell
    ::close(fd);  // drops our shared lock if we got it
    return held;
}

int remove_stale_instance_locks(const std::string& data_dir) {
    int n = 0;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(lock_dir(data_dir), ec)) {
        if (e.path().extension() != ".lock" || !valid_instance(e.path().stem().string())) continue;
        // Removed only while we hold it ourselves and it is still the file of that name: its
        // owner is gone (the kernel dropped its lock at exit, kill -9 included), and a process
        // creating it right now re-checks the name after locking (acquire_instance) and
        // makes a fresh one, so no age rule is needed.
        const std::string path = e.path().string();
        const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        if (fd < 0) continue;
        if (::flock(fd, LOCK_EX | LOCK_NB) == 0 && same_file(fd, path)) {
            std::error_code rec;
            if (fs::remove(e.path(), rec)) ++n;
        }
        ::close(fd);
    }
    return n;
}

}  // namespace fringe
