// capture: replays a capture file as an input-only source (a ReplayPort: it has no output to
// write to); its truth columns, when present, become the run's truth, and its digital a/b/z
// columns, when present, the DUT's position (ABZ readout, docs/abz.md).
#include "abz.hpp"
#include "capture_file.hpp"
#include "device.hpp"

#include "signal_gen/base/config.hpp"

#include <algorithm>
#include <limits>
#include <map>
#include <optional>

namespace fringe::dev {

namespace {

class CaptureSource final : public Device, public ReplayPort {
public:
    CaptureSource(std::string uri, const std::string& path, const CaptureOptions& opts, const nlohmann::json& s)
        : uri_(std::move(uri)), reader_(path, opts), channels_(opts.channels) {
        if (reader_.columns().abz()) {
            if (s.value("interpolation", nlohmann::json()).is_null())
                throw DeviceError(uri_, "the capture has A/B lines (a DUT's quadrature output): give the DUT's interpolation factor, "
                                        "interpolation=N (A/B periods per electrical cycle, 4N counts)");
            abz_cfg_.interpolation = s["interpolation"].get<int>();
            abz_cfg_.index_count = s.value("index_count", 0LL);
            abz_cfg_.offset_rad = s.value("offset_rad", 0.0);
            if (abz_cfg_.interpolation > 0) abz_.emplace(abz_cfg_);  // 0: the lines are left unread
        }
    }
    ReplayPort* replay() override { return this; }

protected:
    DeviceInfo describe() const override {
        DeviceInfo i;
        i.driver = "capture";
        i.uri = uri_;
        i.description = "replay of " + reader_.path();
        const auto& m = reader_.meta();  // a capture's metadata is not trusted to have the right types
        i.board_id = m.contains("board_id") && m["board_id"].is_string() ? m["board_id"].get<std::string>() : "capture";
        i.settings = {{"path", reader_.path()}, {"has_truth", reader_.columns().theta_true}};
        for (const auto& [col, ch] : channels_) i.settings[col] = ch;
        if (abz_) {
            i.dut_position = true;
            i.settings["interpolation"] = abz_cfg_.interpolation;
            i.settings["index_count"] = abz_cfg_.index_count;
            i.settings["offset_rad"] = abz_cfg_.offset_rad;
            i.settings["has_index"] = reader_.columns().z;
        }
        return i;
    }

public:
    void start(double fs) override {
        const double file_fs = reader_.sample_rate_hz();
        if (file_fs > 0 && std::fabs(file_fs - fs) > 1e-9 * fs)
            throw DeviceError(uri_, "capture is at " + std::to_string(file_fs) + " Hz, the run at " + std::to_string(fs) + " Hz");
    }
    StreamResult read(std::span<double> s, std::span<double> c, int) override {
        StreamResult r;
        r.first_index = index_;
        if (pos_ >= buf_.size()) {
            buf_.clear();
            pos_ = 0;
            if (!reader_.read(65536, buf_)) return r;  // end of file: 0 frames
            if (abz_) {  // the DUT's position for the whole block, in order
                dut_.resize(buf_.size());
                abz_->process(buf_.size(), buf_.t_s.data(), buf_.a.data(), buf_.b.data(), buf_.z.empty() ? nullptr : buf_.z.data(),
                              buf_.theta_true_rad.empty() ? nullptr : buf_.theta_true_rad.data(), dut_.data());
            }
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
    bool last_dut(std::span<double> th) override {
        if (!abz_) return false;
        for (std::size_t i = 0; i < last_n_ && i < th.size(); ++i) th[i] = dut_[last_pos_ + i];
        return true;
    }
    nlohmann::json dut_readout() const override { return abz_ ? abz_->to_json() : nlohmann::json(); }

private:
    std::string uri_;
    CaptureReader reader_;
    std::map<std::string, std::string> channels_;
    AbzConfig abz_cfg_;
    std::optional<AbzDecoder> abz_;
    std::vector<double> dut_;
    CaptureData buf_;
    std::size_t pos_ = 0, last_pos_ = 0, last_n_ = 0;
    std::uint64_t index_ = 0;
};

}  // namespace

}  // namespace fringe::dev

namespace fringe {
CaptureOptions capture_options_from_uri(const nlohmann::json& s) {
    CaptureOptions opts;
    // A replay streams one block at a time: the limit bounds time, not memory. Uploaded
    // captures were held to the service's own limit when they arrived.
    opts.max_expanded_bytes = static_cast<std::uint64_t>(std::min(s.value("max_expanded_mb", 4096.0), 1.6e7) * 1048576.0);
    for (const char* col : {"sin", "cos", "theta_true", "omega_true", "index", "a", "b", "z"})
        if (s.contains(col) && s[col].is_string()) opts.channels[col] = s[col].get<std::string>();
    return opts;
}
}  // namespace fringe

namespace fringe::dev {

void register_capture(std::vector<DriverInfo>& r) {
    DriverInfo d;
    d.scheme = "capture";
    d.summary = "Replay a capture file (.csv with sidecar, .fcap, or a sigrok session .sr) as the input stream; its theta_true becomes "
                "the truth, its a/b/z lines the DUT's position (ABZ readout)";
    for (const char* col : {"sin", "cos", "theta_true", "omega_true", "index", "a", "b", "z"})
        d.settings.push_back({col, "", ParamType::String, nullptr, -kInf, kInf, {},
                              std::string("sigrok session (.sr) channel read as column ") + col + " (default: the channel named " + col + ")"});
    d.settings.push_back({"interpolation", "", ParamType::Integer, nullptr, 0, 1000000, {},
                          "the DUT's interpolation factor N: A/B periods per electrical cycle (4N counts); required when the capture has a/b lines "
                          "(0: leave them unread, no DUT lane)"});
    d.settings.push_back({"max_expanded_mb", "MiB", ParamType::Number, 4096.0, 1, 1.6e7, {},
                          "most sample data a sigrok session (.sr) may expand to (its members as declared; a limit against ZIP bombs)"});
    d.settings.push_back({"index_count", "", ParamType::Integer, 0, -1e9, 1e9, {}, "the DUT's count at its Z index, mod 4N (docs/abz.md)"});
    d.settings.push_back({"offset_rad", "rad", ParamType::Number, 0.0, -1e3, 1e3, {}, "electrical angle of count 0's lower edge (docs/abz.md)"});
    d.open = [](const std::string& uri, const std::string& path, const nlohmann::json& s) -> std::unique_ptr<Device> {
        if (path.empty()) throw ConfigError("device", "capture needs a file: capture:/path/to/x.fcap");
        const CaptureOptions opts = capture_options_from_uri(s);
        try {
            return std::make_unique<CaptureSource>(uri, path, opts, s);
        } catch (const CaptureError& e) {
            throw DeviceError(uri, e.what());
        } catch (const std::invalid_argument& e) {
            throw DeviceError(uri, e.what());
        }
    };
    r.push_back(std::move(d));
}

}  // namespace fringe::dev
