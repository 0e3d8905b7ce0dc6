// Who owns a data folder and which runs in it are still alive, from flock(2) locks rather
// than PIDs (a restarted service in a container is PID 1 again; PIDs are reused).
//
// - DATA/lock: held exclusively by the one `fringe serve` of that folder for its lifetime. A
//   second service on the same folder cannot take it and says who holds it (pid and
//   instance id, written into the file).
// - DATA/locks/INSTANCE.lock: every process that records runs in DATA/runs.db (the service,
//   each `fringe run --data`) holds one for its lifetime and stamps its rows with INSTANCE.
//   A row still "queued"/"running" whose instance lock nobody holds belongs to a process
//   that is gone: the run is interrupted. The kernel drops a lock when its holder dies
//   (kill -9 included), so the answer never depends on a PID.
#pragma once

#include <stdexcept>
#include <string>

namespace fringe {

// 64 random bits, hex: one per process start.
std::string new_instance_id();

class InstanceLock {
public:
    InstanceLock() = default;
    ~InstanceLock();
    InstanceLock(const InstanceLock&) = delete;
    InstanceLock& operator=(const InstanceLock&) = delete;

    // Takes DATA/lock exclusively for a service (throws InstanceLockBusy naming the folder and
    // the holder's pid and instance id if another process has it) and DATA/locks/ID.lock.
    void acquire_service(const std::string& data_dir, const std::string& instance_id);
    // Takes DATA/locks/ID.lock only (a CLI run: it may run beside a service).
    void acquire_instance(const std::string& data_dir, const std::string& instance_id);
    const std::string& id() const { return id_; }

private:
    int service_fd_ = -1, instance_fd_ = -1;
    std::string id_, instance_path_;
};

class InstanceLockBusy : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

// True if some process holds DATA/locks/ID.lock (the instance that wrote a row is alive).
bool instance_alive(const std::string& data_dir, const std::string& instance_id);
// Removes lock files of instances that are gone (killed ones leave theirs): each is locked
// first and removed only while still unheld by anyone else. Returns how many.
int remove_stale_instance_locks(const std::string& data_dir);

}  // namespace fringe
