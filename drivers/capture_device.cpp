// capture: replays a capture file as the input stream (the output is ignored); its truth
// columns, when present, become the run's truth.
#include "capture_file.hpp"
#include "device.hpp"

#include "signal_gen/config.hpp"

#include <limits>

namespace fringe::dev {

namespace {

class CaptureSource final : public Device {
public:
    CaptureSource(std::string uri, const std::string& path) : uri_(std::move(uri)), reader_(path) {}
    DeviceInfo info() const override {
        DeviceInfo i;
        i.driver = "capture";
        i.uri = uri_;
        i.description = "replay of " + reader_.path();
        const auto& m = reader_.meta();  // a capture's metadata is not trusted to have the right types
        i.board_id = m.contains("board_id") && m["board_id"].is_string() ? m["board_id"].get<std::string>() : "capture";
        i.streaming = true;
        i.needs_output = false;
        i.settings = {{"path", reader_.path()}, {"has_truth", reader_.columns().theta_true}};
        return i;
    }
    void start(double fs) override {
        const double file_fs = reader_.sample_rate_hz();
        if (file_fs > 0 && std::fabs(file_fs - fs) > 1e-9 * fs)
            throw DeviceError(uri_, "capture is at " + std::to_string(file_fs) + " Hz, the run at " + std::to_string(fs) + " Hz");
    }
    StreamResult write(std::span<const double> s, std::span<const double>) override { return {StreamStatus::Ok, s.size(), 0, 0, {}}; }
    StreamResult read(std::span<double> s, std::span<double> c, int) override {
        StreamResult r;
        r.first_index = index_;
        if (pos_ >= buf_.size()) {
            buf_.clear();
            pos_ = 0;
            if (!reader_.read(65536, buf_)) return r;  // end of file: 0 frames
        }
        const std::size_t n = std::min(s.size(), buf_.size() - pos_);
        for (std::size_t i = 0; i < n; ++i) { s[i] = buf_.sin_v[pos_ + i]; c[i] = buf_.cos_v[pos_ + i]; }
        last_pos_ = pos_;
        last_n_ = n;
        pos_ += n;
        index_ += n;
        r.frames = n;
        return r;
    }
    bool last_truth(std::span<double> th, std::span<double> om) override {
        if (buf_.theta_true_rad.empty()) return false;
        for (std::size_t i = 0; i < last_n_ && i < th.size(); ++i) {
            th[i] = buf_.theta_true_rad[last_pos_ + i];
            // No rate truth in the file: unknown, not zero (the run then has no rate metrics).
            om[i] = buf_.omega_true_rad_s.empty() ? std::numeric_limits<double>::quiet_NaN() : buf_.omega_true_rad_s[last_pos_ + i];
        }
        return true;
    }
    void stop() override {}

private:
    std::string uri_;
    CaptureReader reader_;
    CaptureData buf_;
    std::size_t pos_ = 0, last_pos_ = 0, last_n_ = 0;
    std::uint64_t index_ = 0;
};

}  // namespace

void register_capture(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "capture";
    d.summary = "Replay a capture file (.csv with sidecar, or .fcap) as the input stream; its theta_true becomes the truth";
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json&) -> std::unique_ptr<Device> {
        if (path.empty()) throw ConfigError("device", "capture needs a file: capture:/path/to/x.fcap");
        try {
            return std::make_unique<CaptureSource>(uri, path);
        } catch (const CaptureError& e) {
            throw DeviceError(uri, e.what());
        }
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
