#include "server/report/report_formats.hpp"

#include "server/analysis/metrics.hpp"

#include "signal_gen/base/text.hpp"
#include "signal_gen/base/constants.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace fringe {

using nlohmann::json;

// Text from a scenario or a device may hold anything: XML 1.0 forbids C0 controls but tab,
// LF and CR (written as references so attribute values keep them), and the document must be
// UTF-8 (other bytes become U+FFFD). Forbidden controls are shown as \xNN.
std::string xml_escape(const std::string& s) {
    const std::string u = sanitize_utf8(s);
    std::string o;
    o.reserve(u.size());
    char hex[8];
    for (std::size_t i = 0; i < u.size(); ++i) {
        const char c = u[i];
        switch (c) {
            case '&': o += "&amp;"; break;
            case '<': o += "&lt;"; break;
            case '>': o += "&gt;"; break;
            case '"': o += "&quot;"; break;
            case '\'': o += "&apos;"; break;
            case '\t': o += "&#9;"; break;
            case '\n': o += "&#10;"; break;
            case '\r': o += "&#13;"; break;
            default:
                if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) {
                    std::snprintf(hex, sizeof hex, "\\x%02x", static_cast<unsigned>(static_cast<unsigned char>(c)));
                    o += hex;
                } else if (u.compare(i, 3, "\xef\xbf\xbe") == 0 || u.compare(i, 3, "\xef\xbf\xbf") == 0) {  // U+FFFE, U+FFFF: not XML characters
                    o += "\xef\xbf\xbd";
                    i += 2;
                } else {
                    o += c;
                }
        }
    }
    return o;
}

void write_file_atomic(const std::string& path, const std::string& text) {
    // A device, FIFO or terminal (/dev/null, /dev/stdout, a pipe to another program) is written
    // in place: a file renamed over it would replace it (as root, /dev/null itself).
    std::error_code ec;
    const auto st = std::filesystem::status(path, ec);
    if (!ec && std::filesystem::exists(st) && !std::filesystem::is_regular_file(st)) {
        if (std::filesystem::is_directory(st)) throw std::runtime_error(path + ": is a directory");
        std::ofstream f(path, std::ios::binary);
        if (!f) throw std::runtime_error(path + ": cannot write");
        f << text;
        f.flush();
        if (!f) throw std::runtime_error(path + ": write failed");
        return;
    }
    const std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp, std::ios::binary);
        if (!f) throw std::runtime_error(path + ": cannot write");
        f << text;
        f.flush();
        if (!f) throw std::runtime_error(path + ": write failed");
    }
    std::filesystem::rename(tmp, path);
}

namespace {
// j[a][b], or null when either level is missing (statistics of an unscored estimator are null).
json sub(const json& j, const char* a, const char* b) {
    if (!j.is_object() || !j.contains(a) || !j[a].is_object() || !j[a].contains(b)) return json();
    return j[a][b];
}
std::string num(const json& v) {
    if (!v.is_number()) return "";
    std::ostringstream os;
    os.precision(6);
    os << v.get<double>();
    return os.str();
}
// A 95 % interval [lo, hi] as "lo..hi", "" when there is none.
std::string interval(const json& iv) {
    if (!iv.is_array() || iv.size() != 2 || !iv[0].is_number() || !iv[1].is_number()) return "";
    std::ostringstream os;
    os.precision(4);
    os << iv[0].get<double>() << ".." << iv[1].get<double>();
    return os.str();
}
}  // namespace

std::string junit_xml(const json& r) {
    const auto& ms = r["measurements"];
    int failures = 0, errors = 0;
    for (const auto& m : ms) {
        if (m["outcome"] == "FAIL") ++failures;
        if (m["outcome"] == "ERROR") ++errors;
    }
    const bool run_error = r["status"] != "done";
    std::ostringstream x;
    const std::string name = r["scenario"].value("name", std::string("run"));
    x << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
    x << "<testsuites name=\"fringe\">\n";
    x << "  <testsuite name=\"" << xml_escape(name) << "\" tests=\"" << (ms.size() + (run_error ? 1 : 0)) << "\" failures=\"" << failures
      << "\" errors=\"" << (errors + (run_error ? 1 : 0)) << "\" timestamp=\"" << xml_escape(r.value("started_at", std::string())) << "\" time=\""
      << num(r.value("wall_s", json())) << "\">\n";
    x << "    <properties>\n";
    x << "      <property name=\"run_id\" value=\"" << xml_escape(r.value("id", std::string())) << "\"/>\n";
    x << "      <property name=\"verdict\" value=\"" << xml_escape(r.value("verdict", std::string())) << "\"/>\n";
    // A report of any age or shape renders: missing keys are skipped, never looked up.
    x << "      <property name=\"seed\" value=\"" << r.value("seed", json()).dump() << "\"/>\n";
    if (r.contains("device") && r["device"].is_object()) x << "      <property name=\"device\" value=\"" << xml_escape(r["device"].value("uri", std::string())) << "\"/>\n";
    // Preflight and convention warnings: what the verdict was reached under.
    for (const auto& w : r.value("warnings", json::array()))
        x << "      <property name=\"warning\" value=\"" << xml_escape(w.value("code", std::string()) + ": " + w.value("message", std::string())) << "\"/>\n";
    // Every metric of the table, per lane: "value unit (95 % lo..hi)" or "not measured: why".
    for (const auto& c : report_metrics(r)) {
        std::string v = c.value ? num(json(*c.value)) + (c.info->unit.empty() ? "" : " " + c.info->unit) : "not measured: " + c.why;
        if (c.interval_95) v += " (95 % " + interval(json::array({c.interval_95->first, c.interval_95->second})) + ")";
        x << "      <property name=\"metric." << xml_escape(c.lane + "." + c.info->name) << "\" value=\"" << xml_escape(v) << "\"/>\n";
    }
    // A calibrated run: its status, both captures, and each lane's rms before and after.
    if (const json c = r.value("calibration", json()); c.is_object()) {
        auto prop = [&](const std::string& n, const std::string& v) { x << "      <property name=\"" << xml_escape(n) << "\" value=\"" << xml_escape(v) << "\"/>\n"; };
        prop("calibration.status", c.value("status", std::string()) + (c.value("why", json()).is_string() ? ": " + c["why"].get<std::string>() : ""));
        for (const char* k : {"computed_on", "verified_on"})
            if (const json p = c.value(k, json()); p.is_object())
                prop(std::string("calibration.") + k, "seed " + (p.value("seed", json()).is_number() ? p["seed"].dump() : std::string("not recorded")) + ", device " + p.value("device", std::string()) +
                                                          (p.value("capture", json()).is_string() ? ", capture " + p["capture"].get<std::string>() : ""));
        for (const auto& l : c.value("lanes", json::array())) {
            const std::string lane = l.value("label", std::string());
            for (const char* pass : {"before", "after"})
                if (const json f = l.value(pass, json()); f.is_object() && f.value("rms_rad", json()).is_number())
                    prop("calibration." + lane + ".rms_" + pass + "_rad", num(f["rms_rad"]) + " (" + f.value("error_source", std::string()) + ")");
        }
    }
    x << "    </properties>\n";
    if (run_error)
        x << "    <testcase classname=\"" << xml_escape(name) << "\" name=\"run\"><error message=\""
          << xml_escape(r["error"].is_string() ? r["error"].get<std::string>() : "") << "\"/></testcase>\n";
    for (const auto& m : ms) {
        const std::string est = m["estimator"].get<std::string>(), metric = m["metric"].get<std::string>();
        x << "    <testcase classname=\"" << xml_escape(name + "." + est) << "\" name=\"" << xml_escape(metric) << "\">\n";
        x << "      <properties>\n";
        x << "        <property name=\"value\" value=\"" << num(m["value"]) << "\"/>\n";
        x << "        <property name=\"unit\" value=\"" << xml_escape(m["unit"].get<std::string>()) << "\"/>\n";
        if (const std::string iv = interval(m.value("interval_95", json())); !iv.empty())
            x << "        <property name=\"interval_95\" value=\"" << iv << "\"/>\n";
        if (m["limit"].contains("max")) x << "        <property name=\"max\" value=\"" << num(m["limit"]["max"]) << "\"/>\n";
        if (m["limit"].contains("min")) x << "        <property name=\"min\" value=\"" << num(m["limit"]["min"]) << "\"/>\n";
        // An interface band's limit has no marginal fraction (its mounting band is the margin).
        if (m["limit"].contains("marginal_fraction"))
            x << "        <property name=\"marginal_fraction\" value=\"" << num(m["limit"]["marginal_fraction"]) << "\"/>\n";
        if (m.value("grade", json()).is_string()) x << "        <property name=\"grade\" value=\"" << xml_escape(m["grade"].get<std::string>()) << "\"/>\n";
        x << "        <property name=\"outcome\" value=\"" << xml_escape(m["outcome"].get<std::string>()) << "\"/>\n";
        if (m.value("implicit", false)) x << "        <property name=\"evidence\" value=\"true\"/>\n";
        if (m.contains("reason")) x << "        <property name=\"reason\" value=\"" << xml_escape(m["reason"].get<std::string>()) << "\"/>\n";
        x << "      </properties>\n";
        const std::string iv = interval(m.value("interval_95", json()));
        const std::string what = est + " " + metric + " = " + (m["value"].is_number() ? num(m["value"]) : std::string("unmeasured")) + " " +
                                 m["unit"].get<std::string>() + (iv.empty() ? std::string() : " (95 % " + iv + ")");
        // The limit it was held to, in the message a CI log shows (not only in the properties).
        std::string unit;
        if (!m["unit"].get<std::string>().empty()) {
            unit += ' ';
            unit += m["unit"].get<std::string>();
        }
        std::string lim;
        if (m["limit"].contains("min") && m["limit"].contains("max"))
            lim = num(m["limit"]["min"]) + " <= " + metric + " <= " + num(m["limit"]["max"]) + unit;
        else if (m["limit"].contains("max"))
            lim = "<= " + num(m["limit"]["max"]) + unit;
        else if (m["limit"].contains("min"))
            lim = ">= " + num(m["limit"]["min"]) + unit;
        if (!lim.empty() && m["limit"].value("marginal_fraction", 0.0) > 0)
            lim += " (marginal within " + num(100.0 * m["limit"]["marginal_fraction"].get<double>()) + " %)";
        const std::string against = lim.empty() ? what : what + ", limit " + lim;
        if (m["outcome"] == "FAIL")
            x << "      <failure message=\"" << xml_escape(m.contains("reason") ? against + ": " + m["reason"].get<std::string>() : against + ": outside its limit") << "\"/>\n";
        if (m["outcome"] == "ERROR") x << "      <error message=\"" << xml_escape(what + ": the run did not complete") << "\"/>\n";
        x << "    </testcase>\n";
    }
    x << "  </testsuite>\n</testsuites>\n";
    return x.str();
}

namespace {

const char* kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};

// Inline SVG plot (issue 11): linear or log axes with tick values and units, and layers that
// never join samples that are not neighbours: points, polylines broken at nulls, min/max bands.
struct Axis {
    std::string label;
    bool log = false;
    double lo = 1e300, hi = -1e300;
    void see(const json& v) {
        if (!v.is_number()) return;
        const double x = v.get<double>();
        if (!std::isfinite(x) || (log && x <= 0)) return;
        lo = std::min(lo, x);
        hi = std::max(hi, x);
    }
    void see_all(const json& a) {
        if (a.is_array())
            for (const auto& v : a) see(v);
    }
    void finish(double pad = 0.05) {
        if (lo > hi) { lo = log ? 1 : -1; hi = log ? 10 : 1; }
        if (!log && pad == 0 && hi > lo) return;
        if (log) {
            if (hi <= lo) hi = lo * 10;
            lo = std::pow(10, std::floor(std::log10(lo)));
            hi = std::pow(10, std::ceil(std::log10(hi)));
            return;
        }
        double d = (hi - lo) * pad;
        if (d == 0) d = std::fabs(hi) * 0.1 + 1e-12;
        lo -= d;
        hi += d;
    }
    double frac(double v) const { return log ? (std::log10(v) - std::log10(lo)) / (std::log10(hi) - std::log10(lo)) : (v - lo) / (hi - lo); }
    std::vector<double> ticks() const {
        std::vector<double> t;
        if (log) {
            const int step = std::max(1, static_cast<int>(std::ceil((std::log10(hi) - std::log10(lo)) / 6)));
            // Few decades: 2x and 5x between them too, so the axis is labelled inside, not only at its ends.
            const bool fill = std::log10(hi) - std::log10(lo) < 2.5;
            for (int e = static_cast<int>(std::floor(std::log10(lo))); e <= static_cast<int>(std::ceil(std::log10(hi))); e += step)
                for (double m : fill ? std::vector<double>{1, 2, 5} : std::vector<double>{1}) {
                    const double v = m * std::pow(10.0, e);
                    if (v >= lo * 0.999 && v <= hi * 1.001) t.push_back(v);
                }
            return t;
        }
        const double raw = (hi - lo) / 5, mag = std::pow(10, std::floor(std::log10(raw)));
        const double n = raw / mag, step = (n < 1.5 ? 1 : n < 3.5 ? 2 : n < 7.5 ? 5 : 10) * mag;
        for (double v = std::ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) t.push_back(std::fabs(v) < step * 1e-9 ? 0 : v);
        return t;
    }
};

// A tick label a person reads at a glance: 0.25, 120, 1.5e-5 (not 1.5e-05), 3e+06 as 3e6.
std::string fmt_num(double v) {
    if (v == 0) return "0";
    if (!std::isfinite(v)) return std::isnan(v) ? "nan" : v > 0 ? "inf" : "-inf";  // never reached by a metric (not measured), but never a crash
    char b[32];
    const double a = std::fabs(v);
    if (a < 1e7 && v == std::floor(v)) {  // counts and round ticks in full: 90000 samples, not 9e+04
        std::snprintf(b, sizeof b, "%.0f", v);
        return b;
    }
    if (a >= 1e-2 && a < 1e5) {
        std::snprintf(b, sizeof b, "%.3g", v);
        return b;
    }
    std::snprintf(b, sizeof b, "%.2e", v);  // d.dde[+-]XX: drop the mantissa's trailing zeros and the exponent's padding
    const char* e = std::strchr(b, 'e');
    const char* end = e;
    while (end > b && end[-1] == '0') --end;
    if (end > b && end[-1] == '.') --end;
    const bool neg = e[1] == '-';
    const char* x = e + 2;
    while (x[0] == '0' && x[1] != '\0') ++x;
    return std::string(b, static_cast<std::size_t>(end - b)) + (neg ? "e-" : "e") + x;
}

class SvgPlot {
public:
    SvgPlot(std::string id, std::string title, Axis x, Axis y, double w = 640, double h = 360)
        : id_(std::move(id)), title_(std::move(title)), x_(std::move(x)), y_(std::move(y)), W(w), H(h) {
        s_.precision(5);
    }
    bool in(double x, double y) const {
        return std::isfinite(x) && std::isfinite(y) && (!x_.log || x > 0) && (!y_.log || y > 0);
    }
    double X(double x) const { return L + std::clamp(x_.frac(x), -0.02, 1.02) * (W - L - R); }
    double Y(double y) const { return H - B - std::clamp(y_.frac(y), -0.02, 1.02) * (H - T - B); }
    // Points only: no line between samples.
    void points(const json& xs, const json& ys, const char* col, double r = 1.3) {
        s_ << "<g class=\"points\" fill=\"" << col << "\">";
        for (std::size_t i = 0; i < xs.size() && i < ys.size(); ++i)
            if (xs[i].is_number() && ys[i].is_number() && in(xs[i].get<double>(), ys[i].get<double>()))
                s_ << "<circle cx=\"" << X(xs[i].get<double>()) << "\" cy=\"" << Y(ys[i].get<double>()) << "\" r=\"" << r << "\"/>";
        s_ << "</g>";
    }
    // A line through consecutive entries, broken where either is null; closed joins the last to the first.
    void line(const json& xs, const json& ys, const char* col, bool closed = false, double width = 1.2) {
        std::vector<std::vector<std::pair<double, double>>> runs(1);
        const std::size_t n = std::min(xs.size(), ys.size());
        for (std::size_t i = 0; i < n; ++i) {
            if (xs[i].is_number() && ys[i].is_number() && in(xs[i].get<double>(), ys[i].get<double>()))
                runs.back().push_back({X(xs[i].get<double>()), Y(ys[i].get<double>())});
            else if (!runs.back().empty())
                runs.emplace_back();
        }
        if (closed && runs.size() == 1 && runs[0].size() == n && n > 2) runs[0].push_back(runs[0].front());
        for (const auto& r : runs) {
            if (r.empty()) continue;
            s_ << "<polyline fill=\"none\" stroke=\"" << col << "\" stroke-width=\"" << width << "\" points=\"";
            for (const auto& [px, py] : r) s_ << px << "," << py << " ";
            s_ << "\"/>";
        }
    }
    // The region between lo and hi over x, one polygon per run of entries where both are numbers.
    void band(const json& xs, const json& lo, const json& hi, const char* col, double opacity = 0.35) {
        const std::size_t n = std::min({xs.size(), lo.size(), hi.size()});
        std::size_t i = 0;
        while (i < n) {
            auto ok = [&](std::size_t k) { return xs[k].is_number() && lo[k].is_number() && hi[k].is_number(); };
            if (!ok(i)) { ++i; continue; }
            std::size_t j = i;
            while (j < n && ok(j)) ++j;
            s_ << "<polygon fill=\"" << col << "\" fill-opacity=\"" << opacity << "\" stroke=\"" << col << "\" stroke-width=\"0.6\" points=\"";
            for (std::size_t k = i; k < j; ++k) s_ << X(xs[k].get<double>()) << "," << Y(hi[k].get<double>()) << " ";
            for (std::size_t k = j; k-- > i;) s_ << X(xs[k].get<double>()) << "," << Y(lo[k].get<double>()) << " ";
            s_ << "\"/>";
            i = j;
        }
    }
    // A labelled vertical marker (e.g. a harmonic order on a frequency axis), drawn at the top.
    void vmark(double x, const std::string& text) {
        if (!in(x, y_.log ? y_.hi : 0) || x < x_.lo || x > x_.hi) return;
        s_ << "<line x1=\"" << X(x) << "\" x2=\"" << X(x) << "\" y1=\"" << T << "\" y2=\"" << H - B << "\" stroke=\"#bbb\" stroke-dasharray=\"2,3\"/>";
        if (!text.empty()) s_ << "<text x=\"" << X(x) << "\" y=\"" << T - 3 << "\" text-anchor=\"middle\" font-size=\"9\">" << xml_escape(text) << "</text>";
    }
    // Legends in a row between the title and the plot area: inside it they covered data.
    void legend(const std::string& name, const char* col, bool dashed = false) {
        const double y = T - 16;
        s_ << "<g class=\"legend\"><line x1=\"" << legend_x_ << "\" x2=\"" << legend_x_ + 14 << "\" y1=\"" << y - 4 << "\" y2=\"" << y - 4 << "\" stroke=\"" << col
           << "\" stroke-width=\"" << (dashed ? 1.2 : 4) << "\"" << (dashed ? " stroke-dasharray=\"3,2\"" : "") << "/><text x=\"" << legend_x_ + 18 << "\" y=\"" << y
           << "\" fill=\"" << col << "\" font-size=\"11\">" << xml_escape(name) << "</text></g>";
        legend_x_ += 28 + 6.2 * static_cast<double>(name.size());
        ++legends_;
    }
    // A shaded span of x (the settle time), with its words at the top.
    void xspan(double x0, double x1, const std::string& text) {
        const double a = X(std::max(x0, x_.lo)), b = X(std::min(x1, x_.hi));
        if (!(b > a)) return;
        s_ << "<g class=\"settle\"><rect x=\"" << a << "\" y=\"" << T << "\" width=\"" << b - a << "\" height=\"" << H - T - B
           << "\" fill=\"#8c959f\" fill-opacity=\"0.25\"/><text x=\"" << a + 3 << "\" y=\"" << T + 12 << "\" font-size=\"10\" fill=\"#57606a\">"
           << xml_escape(text) << "</text></g>";
    }
    // A dashed horizontal line (a limit) across the plot, labelled at its right end.
    void hline(double y, const std::string& text, const char* col) {
        if (!in(x_.log ? x_.hi : 0, y) || y < y_.lo || y > y_.hi) return;
        s_ << "<g class=\"limit\"><line x1=\"" << L << "\" x2=\"" << W - R << "\" y1=\"" << Y(y) << "\" y2=\"" << Y(y) << "\" stroke=\"" << col
           << "\" stroke-width=\"1.3\" stroke-dasharray=\"6,4\"/><text x=\"" << W - R - 3 << "\" y=\"" << Y(y) - 3
           << "\" text-anchor=\"end\" font-size=\"10\" fill=\"" << col << "\">" << xml_escape(text) << "</text></g>";
    }
    // A label at the bottom of the plot area beside x (e.g. "Nyquist" at its marker).
    void xspan_label(double x, const std::string& text) {
        if (!in(x, y_.log ? y_.hi : 0) || x < x_.lo || x > x_.hi) return;
        s_ << "<text class=\"nyquist\" x=\"" << X(x) - 3 << "\" y=\"" << H - B - 4 << "\" text-anchor=\"end\" font-size=\"10\" fill=\"#57606a\">"
           << xml_escape(text) << "</text>";
    }
    // The height that makes the plot area square for a width (a Lissajous drawn 1:1).
    static double square_height(double w) { return w - L - R + T + B; }
    void note(const std::string& text) {
        s_ << "<text x=\"" << (L + W - R) / 2 << "\" y=\"" << (T + H - B) / 2 << "\" text-anchor=\"middle\" fill=\"#666\">" << xml_escape(text) << "</text>";
    }
    std::string str() const {
        std::ostringstream o;
        o.precision(5);
        o << "<svg id=\"" << id_ << "\" class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H << "\" viewBox=\"0 0 " << W
          << " " << H << "\">";
        o << "<text x=\"" << W / 2 << "\" y=\"14\" text-anchor=\"middle\" font-weight=\"bold\">" << xml_escape(title_) << "</text>";
        o << "<rect x=\"" << L << "\" y=\"" << T << "\" width=\"" << W - L - R << "\" height=\"" << H - T - B << "\" fill=\"none\" stroke=\"#999\"/>";
        // Gridlines across the plot at every tick, both axes, and a label at each tick.
        for (double t : x_.ticks()) {
            const double px = L + x_.frac(t) * (W - L - R);
            o << "<line class=\"grid\" x1=\"" << px << "\" x2=\"" << px << "\" y1=\"" << T << "\" y2=\"" << H - B + 4 << "\" stroke=\"#e4e4e4\"/>";
            o << "<text class=\"xtick\" x=\"" << px << "\" y=\"" << H - B + 15 << "\" text-anchor=\"middle\" font-size=\"11\">" << fmt_num(t) << "</text>";
        }
        for (double t : y_.ticks()) {
            const double py = H - B - y_.frac(t) * (H - T - B);
            o << "<line class=\"grid\" x1=\"" << L - 4 << "\" x2=\"" << W - R << "\" y1=\"" << py << "\" y2=\"" << py << "\" stroke=\"#e4e4e4\"/>";
            o << "<text class=\"ytick\" x=\"" << L - 6 << "\" y=\"" << py + 4 << "\" text-anchor=\"end\" font-size=\"11\">" << fmt_num(t) << "</text>";
        }
        o << "<text class=\"xlabel\" x=\"" << (L + W - R) / 2 << "\" y=\"" << H - 6 << "\" text-anchor=\"middle\">" << xml_escape(x_.label) << "</text>";
        o << "<text class=\"ylabel\" x=\"12\" y=\"" << (T + H - B) / 2 << "\" transform=\"rotate(-90 12 " << (T + H - B) / 2
          << ")\" text-anchor=\"middle\">" << xml_escape(y_.label) << "</text>";
        o << s_.str() << "</svg>";
        return o.str();
    }

private:
    std::string id_, title_;
    Axis x_, y_;
    double W, H;
    static constexpr double L = 70, R = 12, T = 46, B = 40;
    std::ostringstream s_;
    int legends_ = 0;
    double legend_x_ = L;
};

// One colour per estimator across every plot: its place in the report's estimators.
struct Palette {
    std::vector<std::string> order;
    explicit Palette(const json& estimators) {
        for (const auto& e : estimators) order.push_back(e.value("label", std::string()));
    }
    const char* operator()(const std::string& label) const {
        for (std::size_t i = 0; i < order.size(); ++i)
            if (order[i] == label) return kColours[i % 6];
        return "#57606a";
    }
};

// Amplitude spectrum of each estimator's error (computed at the full rate by the scorer):
// log-log, Hz below, harmonic orders of the electrical frequency marked along the top.
std::string svg_spectrum(const json& estimators) {
    Axis x{"frequency (Hz); top: orders of the electrical frequency", true}, y{"amplitude (rad)", true};
    std::vector<const json*> with;
    double fe = 0;
    std::string why = "no spectrum in this report";
    for (const auto& e : estimators) {
        if (!e.contains("spectrum") || !e["spectrum"].is_object()) continue;
        const auto& sp = e["spectrum"];
        if (sp["f_hz"].empty()) {
            // A capture without truth: the spectrum is of the error against truth, which it has none of.
            const bool truthless = e.value("metrics", json::object()).value("scored", -1) == 0 &&
                                   e.value("analysers", json::object()).contains("self_reference");
            why = truthless ? "no spectrum: it is the spectrum of the error against truth, and this capture has no truth (theta_true); the "
                              "self-referenced error is in the metrics (self_ref_*)"
                            : "no spectrum: no run of " + sp["segment_samples"].dump() + " contiguous scored samples";
            continue;
        }
        with.push_back(&e);
        x.see_all(sp["f_hz"]);
        y.see_all(sp["amplitude_rad"]);
        if (fe == 0 && sp["electrical_hz"].is_number()) fe = sp["electrical_hz"].get<double>();
    }
    if (with.empty()) return "<p id=\"plot-spectrum\" class=\"no-spectrum\">" + xml_escape(why) + "</p>";
    y.lo = std::max(y.lo, y.hi * 1e-7);  // noise-free runs reach 1e-20: keep the peaks readable
    x.finish();
    y.finish();
    const auto& sp0 = (*with.front())["spectrum"];
    // Harmonic markers only below Nyquist (half the sample rate): above it there are no bins.
    double nyq = sp0.value("sample_rate_hz", json()).is_number() ? sp0["sample_rate_hz"].get<double>() / 2 : 0;
    if (!(nyq > 0))
        for (const json* e : with)
            for (const auto& f : (*e)["spectrum"]["f_hz"]) nyq = std::max(nyq, f.get<double>());
    SvgPlot p("plot-spectrum", "Error spectrum (full rate, Welch, " + sp0["segment_samples"].dump() + "-sample Hann segments)", x, y);
    if (fe > 0)
        for (int k = 1; k <= 16; ++k)
            if (k * fe <= nyq * (1 + 1e-9)) p.vmark(k * fe, (k <= 4 || k % 4 == 0) ? std::to_string(k) + "x" : "");
    p.vmark(nyq, "");
    p.xspan_label(nyq, "Nyquist");
    const Palette colour(estimators);
    for (const json* e : with) {
        const char* col = colour((*e)["label"].get<std::string>());
        p.line((*e)["spectrum"]["f_hz"], (*e)["spectrum"]["amplitude_rad"], col);
        p.legend((*e)["label"].get<std::string>(), col);
    }
    if (fe > 0) p.legend("harmonic orders below Nyquist", "#bbbbbb", true);
    return p.str();
}

// Reports written before issue 11: traces are every stride-th sample. Drawn as points only
// (a line through them would invent the signal between samples), with a note saying so.
std::string stride_plots(const json& tr, const json& estimators) {
    const Palette colour(estimators);
    std::string out = "<p class=\"old-traces\">Old report: traces are stride samples (every " + tr.value("stride", json()).dump() +
                      "th sample), drawn as points; lines between them would alias.</p>\n";
    const json none = json::array();
    auto arr = [&](const char* k) -> const json& { return tr.contains(k) ? tr[k] : none; };
    {
        Axis x{"cos (V)"}, y{"sin (V)"};
        x.see_all(arr("cos_v")); y.see_all(arr("sin_v"));
        const double a = std::max({std::fabs(x.lo), std::fabs(x.hi), std::fabs(y.lo), std::fabs(y.hi), 1e-9}) * 1.05;
        if (x.lo > x.hi || y.lo > y.hi) { x.finish(); y.finish(); } else { x.lo = y.lo = -a; x.hi = y.hi = a; }  // 1:1, as the envelope one
        SvgPlot p("plot-lissajous", "Lissajous (stride samples)", x, y, 380, SvgPlot::square_height(380));
        p.points(arr("cos_v"), arr("sin_v"), kColours[0]);
        out += p.str();
    }
    const json& errs = tr.contains("error_rad") && tr["error_rad"].is_object() ? tr["error_rad"] : json::object();
    {
        Axis x{"electrical angle (rad)"}, y{"error (rad)"};
        x.lo = -kPi; x.hi = kPi;
        for (const auto& [label, e] : errs.items()) y.see_all(e);
        y.finish();
        SvgPlot p("plot-by-angle", "Error vs electrical angle (stride samples)", x, y);
        for (const auto& [label, e] : errs.items()) {
            p.points(arr("theta_true_wrapped_rad"), e, colour(label));
            p.legend(label, colour(label));
        }
        out += p.str();
    }
    {
        Axis x{"time (s)"}, y{"error (rad)"};
        x.see_all(arr("t_s"));
        x.finish(0.0);
        for (const auto& [label, e] : errs.items()) y.see_all(e);
        y.finish();
        SvgPlot p("plot-time", "Error vs time (stride samples)", x, y);
        for (const auto& [label, e] : errs.items()) {
            p.points(arr("t_s"), e, colour(label));
            p.legend(label, colour(label));
        }
        out += p.str();
    }
    return out;
}

// Plots from "kind":"envelope" traces (TraceRecorder) and each estimator's "spectrum" (ErrorSpectrum).
// The scenario's settle time [t0, t0 + settle_s] (not scored), when the report states it.
bool settle_span(const json& r, double& a, double& b) {
    const json sc = r.value("scenario", json::object());
    if (!sc.is_object() || !sc.value("settle_s", json()).is_number() || !(sc["settle_s"].get<double>() > 0)) return false;
    a = sc.value("t0_s", json()).is_number() ? sc["t0_s"].get<double>() : 0.0;
    b = a + sc["settle_s"].get<double>();
    return true;
}

// Limits that bound every sample of an error plot: max_abs_rad (+-max) and max_dev_rad (mean +- max).
struct ErrLimit { std::string label, text; std::vector<double> ys; };
std::vector<ErrLimit> error_limits(const json& r) {
    std::vector<ErrLimit> out;
    for (const auto& m : r.value("measurements", json::array())) {
        if (!m.value("limit", json()).is_object() || !m["limit"].value("max", json()).is_number()) continue;
        const double mx = m["limit"]["max"].get<double>();
        const std::string label = m.value("estimator", std::string()), metric = m.value("metric", std::string());
        if (metric == "max_abs_rad") out.push_back({label, "limit " + label + " |e| <= " + fmt_num(mx) + " rad", {mx, -mx}});
        if (metric == "max_dev_rad")
            for (const auto& e : r.value("estimators", json::array()))
                if (e.value("label", std::string()) == label && sub(e.value("metrics", json()), "mean", "rad").is_number()) {
                    const double mu = sub(e["metrics"], "mean", "rad").get<double>();
                    out.push_back({label, "limit " + label + " |e - mean| <= " + fmt_num(mx) + " rad", {mu + mx, mu - mx}});
                }
    }
    return out;
}

std::string envelope_plots(const json& tr, const json& estimators, const json& report) {
    std::string out;
    const auto limits = error_limits(report);
    const Palette colour(estimators);
    const auto& liss = tr["lissajous"];
    {  // Lissajous: real samples as points, the folded electrical cycle as one closed line
        Axis x{"cos (V)"}, y{"sin (V)"};
        x.see_all(liss["points"]["cos_v"]); y.see_all(liss["points"]["sin_v"]);
        x.see_all(liss["cycle"]["cos_v"]); y.see_all(liss["cycle"]["sin_v"]);
        const double a = std::max({std::fabs(x.lo), std::fabs(x.hi), std::fabs(y.lo), std::fabs(y.hi), 1e-9}) * 1.05;
        x.lo = y.lo = -a; x.hi = y.hi = a;
        SvgPlot p("plot-lissajous", "Lissajous: samples, folded cycle (1:1)", x, y, 380, SvgPlot::square_height(380));
        p.line(liss["cycle"]["cos_v"], liss["cycle"]["sin_v"], kColours[0], true, 1.6);
        p.points(liss["points"]["cos_v"], liss["points"]["sin_v"], "#57606a", 1.1);  // over the mean: their spread shows
        p.legend("samples", "#57606a");
        p.legend("folded cycle", kColours[0]);
        out += p.str();
    }
    {  // error vs electrical angle: mean line, min/max band
        const auto& ba = tr["by_angle"];
        Axis x{"electrical angle (rad)"}, y{"error (rad)"};
        x.lo = 0; x.hi = 2 * kPi;
        for (const auto& [label, f] : ba["error_rad"].items()) { y.see_all(f["min"]); y.see_all(f["max"]); }
        const double peak = std::max(std::fabs(y.lo), std::fabs(y.hi));
        for (const auto& l : limits)  // a limit near the data is kept in view (within 3x of its peak)
            if (ba["error_rad"].contains(l.label))
                for (double v : l.ys) if (std::fabs(v) <= 3 * peak) { y.lo = std::min(y.lo, v); y.hi = std::max(y.hi, v); }
        y.finish();
        SvgPlot p("plot-by-angle", "Error vs electrical angle (mean, min..max)", x, y);
        for (const auto& l : limits)
            if (ba["error_rad"].contains(l.label))
                for (double v : l.ys) p.hline(v, l.text, "#d1242f");
        for (const auto& [label, f] : ba["error_rad"].items()) {
            const char* col = colour(label);
            p.band(ba["theta_rad"], f["min"], f["max"], col, 0.2);
            p.line(ba["theta_rad"], f["mean"], col);
            p.legend(label, col);
        }
        out += p.str();
    }
    {  // error vs time: per-bucket min/max envelope at the full rate
        Axis x{"time (s)"}, y{"error (rad)"};
        x.see_all(tr["t_s"]);
        x.finish(0.0);
        for (const auto& [label, e] : tr["error_rad"].items()) { y.see_all(e["min"]); y.see_all(e["max"]); }
        const double peak = std::max(std::fabs(y.lo), std::fabs(y.hi));
        for (const auto& l : limits)
            if (tr["error_rad"].contains(l.label))
                for (double v : l.ys) if (std::fabs(v) <= 3 * peak) { y.lo = std::min(y.lo, v); y.hi = std::max(y.hi, v); }
        y.finish();
        SvgPlot p("plot-time", "Error vs time (min..max per " + tr["bucket_samples"].dump() + " samples)", x, y);
        double s0, s1;
        if (settle_span(report, s0, s1)) p.xspan(s0, s1, "settle: not scored");
        for (const auto& l : limits)
            if (tr["error_rad"].contains(l.label))
                for (double v : l.ys) p.hline(v, l.text, "#d1242f");
        for (const auto& [label, e] : tr["error_rad"].items()) {
            const char* col = colour(label);
            p.band(tr["t_s"], e["min"], e["max"], col, 0.45);
            p.legend(label, col);
        }
        out += p.str();
    }
    out += svg_spectrum(estimators);
    return out;
}
// Each lane's self-referenced error against the electrical angle (docs/self-reference.md): the
// periodic part its harmonics 1..8 give, e(s) = sum A_k cos(k s - phase_k), the sub-divisional
// error a capture without truth still shows. Its mean is not observable: the curves are about 0.
std::string svg_self_reference(const json& estimators) {
    const Palette colour(estimators);
    std::vector<std::pair<std::string, json>> curves;
    constexpr int kPoints = 256;
    Axis x{"electrical angle of the self-reference (rad)"}, y{"self-referenced error, periodic part (rad)"};
    x.lo = 0;
    x.hi = kTwoPi;
    json xs = json::array();
    for (int i = 0; i <= kPoints; ++i) xs.push_back(kTwoPi * i / kPoints);
    for (const auto& e : estimators) {
        const json sr = e.value("analysers", json::object()).value("self_reference", json());
        if (!sr.is_object() || !sr.value("measured", false) || !sr.value("harmonics", json()).is_array()) continue;
        json ys = json::array();
        for (int i = 0; i <= kPoints; ++i) {
            const double s_rad = kTwoPi * i / kPoints;
            double v = 0;
            for (const auto& hk : sr["harmonics"])
                if (hk.value("amplitude_rad", json()).is_number() && hk.value("phase_rad", json()).is_number())
                    v += hk["amplitude_rad"].get<double>() * std::cos(hk.value("order", 0) * s_rad - hk["phase_rad"].get<double>());
            ys.push_back(v);
            y.see(ys.back());
        }
        curves.push_back({e.value("label", std::string()), std::move(ys)});
    }
    if (curves.empty()) return "";
    y.finish();
    SvgPlot p("plot-self-reference", "Self-referenced error vs electrical angle (harmonics 1-8)", x, y);
    for (const auto& [label, ys] : curves) {
        p.line(xs, ys, colour(label), false, 1.5);
        p.legend(label, colour(label));
    }
    return p.str();
}

std::string svg_bars(const json& estimators) {
    const double W = 640, H = 300, L = 70, R = 12, B = 40, T = 46;  // legend row above the plot area: inside it, it covered the 1x bar
    double vmax = 0;
    for (const auto& e : estimators)
        for (const auto& h : e["metrics"]["harmonics"]) vmax = std::max(vmax, h["amplitude"]["rad"].get<double>());
    if (vmax <= 0) vmax = 1;
    Axis y{"amplitude (rad)"};
    y.lo = 0;
    y.hi = vmax * 1.05;
    std::ostringstream s;
    s.precision(4);
    s << "<svg id=\"plot-harmonics\" class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H << "\" viewBox=\"0 0 " << W << " " << H
      << "\">";
    s << "<text x=\"" << W / 2 << "\" y=\"16\" text-anchor=\"middle\" font-weight=\"bold\">Error harmonics (amplitude, rad)</text>";
    const std::size_t ne = std::max<std::size_t>(estimators.size(), 1);
    int orders = 6;  // every fitted order (16 by default), at least 1x..6x
    for (const auto& e : estimators)
        for (const auto& h : e["metrics"]["harmonics"]) orders = std::max(orders, h["order"].get<int>());
    const double group = (W - L - R) / static_cast<double>(orders), bw = group * 0.8 / static_cast<double>(ne);
    auto Y = [&](double v) { return H - B - y.frac(v) * (H - T - B); };
    s << "<rect x=\"" << L << "\" y=\"" << T << "\" width=\"" << W - L - R << "\" height=\"" << H - T - B << "\" fill=\"none\" stroke=\"#999\"/>";
    for (double t : y.ticks()) {
        s << "<line class=\"grid\" x1=\"" << L - 4 << "\" x2=\"" << W - R << "\" y1=\"" << Y(t) << "\" y2=\"" << Y(t) << "\" stroke=\"#e4e4e4\"/>";
        s << "<text class=\"ytick\" x=\"" << L - 6 << "\" y=\"" << Y(t) + 4 << "\" text-anchor=\"end\" font-size=\"11\">" << fmt_num(t) << "</text>";
    }
    s << "<text x=\"" << (L + W) / 2 << "\" y=\"" << H - 6 << "\" text-anchor=\"middle\">harmonic order (x electrical frequency)</text>";
    s << "<text x=\"12\" y=\"" << (T + H - B) / 2 << "\" transform=\"rotate(-90 12 " << (T + H - B) / 2 << ")\" text-anchor=\"middle\">amplitude (rad)</text>";
    for (int k = 1; k <= orders; ++k) {
        const double px = L + group * (k - 0.5);
        s << "<line class=\"grid\" x1=\"" << L + group * k << "\" x2=\"" << L + group * k << "\" y1=\"" << T << "\" y2=\"" << H - B << "\" stroke=\"#f0f0f0\"/>";
        s << "<text class=\"xtick\" x=\"" << px << "\" y=\"" << H - B + 15 << "\" text-anchor=\"middle\" font-size=\"11\">" << k << "x</text>";
    }
    std::size_t ei = 0;
    double legend_x = L;
    for (const auto& e : estimators) {
        const char* col = kColours[ei % 6];
        for (const auto& h : e["metrics"]["harmonics"]) {
            const int k = h["order"].get<int>();
            const double v = h["amplitude"]["rad"].get<double>();
            const double hh = H - B - Y(v);
            s << "<rect x=\"" << L + group * (k - 1) + group * 0.1 + bw * static_cast<double>(ei) << "\" y=\"" << Y(v) << "\" width=\"" << bw
              << "\" height=\"" << hh << "\" fill=\"" << col << "\"><title>" << xml_escape(e["label"].get<std::string>()) << " " << k << "x: " << fmt_num(v)
              << " rad</title></rect>";
        }
        s << "<g class=\"legend\"><rect x=\"" << legend_x << "\" y=\"" << T - 24 << "\" width=\"12\" height=\"10\" fill=\"" << col << "\"/><text x=\"" << legend_x + 16
          << "\" y=\"" << T - 15 << "\" fill=\"" << col << "\" font-size=\"11\">" << xml_escape(e["label"].get<std::string>()) << "</text></g>";
        legend_x += 28 + 6.2 * static_cast<double>(e["label"].get<std::string>().size());
        ++ei;
    }
    s << "</svg>";
    return s.str();
}

}  // namespace

namespace {

// A metric's value for people: 3 significant digits, its unit, its 95 % interval.
std::string cell_text(const MetricCell& c, bool with_unit) {
    if (!c.value) return "";
    std::string s = fmt_num(*c.value);
    if (with_unit && !c.info->unit.empty()) s += " " + c.info->unit;
    return s;
}
std::string cell_interval(const MetricCell& c) {
    if (!c.interval_95) return "";
    return fmt_num(c.interval_95->first) + ".." + fmt_num(c.interval_95->second);
}

}  // namespace

// The estimators' summary (the table's summary columns) and every metric of every lane.
// The signals graded against the interface profile, as an encoder tester shows them
// (docs/signal-quality.md): a gauge a band, the Lissajous of the run's angle bins drawn 1:1
// with the amplitude band as tolerance rings (radius Vpp / 2), and the per-period recording
// against the period index with the band edges.
std::string signal_section_html(const json& r) {
    const json sq = r.value("signal", json());
    if (!sq.is_object()) return "";
    std::ostringstream h;
    h << "<h2>Signals</h2><div id=\"signal-page\">\n";
    std::vector<json> graded;
    for (const auto& m : r.value("measurements", json::array()))
        if (m.value("estimator", "") == "run" && m.value("interface", json()).is_string()) graded.push_back(m);
    if (graded.empty()) h << "<p class=\"muted\" id=\"signal-interface\">No interface profile: the figures are not graded (a scenario's \"interface\", or --interface).</p>\n";
    else h << "<p id=\"signal-interface\">Graded against <b>" << xml_escape(graded[0]["interface"].get<std::string>()) << "</b>: green within the mounting tolerance, yellow within the specification only, grey outside it.</p>\n";
    if (sq.value("periods", 0) == 0) {
        h << "<p id=\"signal-note\">Signals not analysed: " << xml_escape(sq.value("note", std::string("no whole electrical period"))) << "</p></div>\n";
        return h.str();
    }
    // Gauges: the scale spans the specification and a third of it either side.
    auto pair = [](const json& band, const char* key, double& lo, double& hi) {
        const json v = band.value(key, json());
        if (!v.is_array() || v.size() != 2) return false;
        lo = v[0].is_number() ? v[0].get<double>() : -INFINITY;
        hi = v[1].is_number() ? v[1].get<double>() : INFINITY;
        return true;
    };
    h << "<div class=\"gauges\">";
    for (const auto& m : graded) {
        const json band = m.value("band", json::object());
        double slo = 0, shi = 0, mlo = 0, mhi = 0;
        const bool has_spec = pair(band, "spec", slo, shi), has_mount = pair(band, "mounting", mlo, mhi);
        const bool has_value = m["value"].is_number();
        const double v = has_value ? m["value"].get<double>() : NAN;
        // A one-sided band: the scale runs from the value or 0 to twice the edge.
        double lo = std::isfinite(slo) ? slo : std::min(0.0, std::isfinite(v) ? v : 0.0), hi = std::isfinite(shi) ? shi : 2 * std::fabs(slo) + 1e-12;
        if (!(hi > lo)) hi = lo + 1;
        const double w = hi - lo, x0 = lo - w / 3, x1 = hi + w / 3;
        // A band too wide to scale (its width overflows a double): the value and grade only.
        const bool scaled = std::isfinite(x1 - x0) && x1 > x0;
        constexpr double W = 360, gx = 8, gw = W - 16, gy = 24, gh = 12;
        auto X = [&](double x) { return gx + gw * std::clamp((x - x0) / (x1 - x0), 0.0, 1.0); };
        const std::string metric = m.value("metric", "");
        const auto mi = find_metric(metric);
        // A figure without a summary column (signal_sym_a): its name without the prefix.
        auto label_of = [](std::string n) {
            if (n.rfind("signal_", 0) == 0) n = n.substr(7);
            std::replace(n.begin(), n.end(), '_', ' ');
            return n;
        };
        const std::string unit = m.value("unit", "");
        const std::string outcome = m.value("outcome", "");
        h << "<svg class=\"gauge\" data-metric=\"" << xml_escape(metric) << "\" data-outcome=\"" << xml_escape(outcome) << "\" xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W
          << "\" height=\"60\" viewBox=\"0 0 " << W << " 60\"><text x=\"" << gx << "\" y=\"14\" font-size=\"12\" font-weight=\"bold\">"
          << xml_escape(mi && !mi->column.empty() ? mi->column : label_of(metric)) << "</text><text x=\"" << W - gx << "\" y=\"14\" font-size=\"12\" text-anchor=\"end\">"
          << (has_value ? fmt_num(v) + (unit.empty() ? "" : " " + xml_escape(unit)) : std::string("not measured")) << ": " << xml_escape(m.value("grade", std::string()))
          << "</text>";
        if (!scaled) {
            h << "<text x=\"" << gx << "\" y=\"" << gy + gh << "\" font-size=\"10\">(the band is too wide to draw)</text></svg>";
            continue;
        }
        h << "<rect class=\"out\" x=\"" << gx << "\" y=\"" << gy << "\" width=\"" << gw << "\" height=\"" << gh << "\" fill=\"#d0d7de\"/>";
        if (has_spec)
            h << "<rect class=\"spec\" x=\"" << X(slo) << "\" y=\"" << gy << "\" width=\"" << X(shi) - X(slo) << "\" height=\"" << gh << "\" fill=\"#f2cc60\"/>";
        if (has_mount)
            h << "<rect class=\"mounting\" x=\"" << X(std::max(mlo, slo)) << "\" y=\"" << gy << "\" width=\"" << X(std::min(mhi, shi)) - X(std::max(mlo, slo))
              << "\" height=\"" << gh << "\" fill=\"#4ac26b\"/>";
        if (has_value) {
            const char* col = outcome == "PASS" ? "#1a7f37" : outcome == "MARGINAL" ? "#9a6700" : "#cf222e";
            h << "<path class=\"value\" d=\"M" << X(v) << "," << gy - 4 << " l-5,-6 h10 z M" << X(v) << "," << gy << " v" << gh << "\" stroke=\"" << col
              << "\" stroke-width=\"2\" fill=\"" << col << "\"/>";
        }
        for (double e : {slo, shi})
            if (std::isfinite(e)) h << "<text x=\"" << X(e) << "\" y=\"" << gy + gh + 12 << "\" font-size=\"10\" text-anchor=\"middle\">" << fmt_num(e) << "</text>";
        h << "</svg>";
    }
    h << "</div>\n<div class=\"plots\">";
    // The Lissajous from the angle bins, 1:1, with the amplitude band's rings.
    const json liss = sq.value("lissajous", json());
    std::vector<std::pair<double, std::string>> rings;  // radius V, label
    for (const auto& m : graded) {
        const std::string metric = m.value("metric", "");
        if (metric != "signal_vpp_a_v" && !(metric == "signal_vpp_b_v" && rings.empty())) continue;
        rings.clear();
        const json band = m.value("band", json::object());
        for (const char* key : {"spec", "mounting"}) {
            const json v = band.value(key, json());
            if (v.is_array())
                for (const auto& e : v)
                    if (e.is_number() && e.get<double>() > 0) rings.push_back({e.get<double>() / 2, std::string(key) + " " + fmt_num(e.get<double>()) + " Vpp"});
        }
    }
    if (liss.is_object()) {
        Axis x{"B (V)"}, y{"A (V)"};
        double a = 1e-9;
        for (const char* k : {"r_max_v"})
            for (const auto& v : liss.value(k, json::array()))
                if (v.is_number()) a = std::max(a, v.get<double>());
        for (const auto& [rad, text] : rings) a = std::max(a, rad);
        a *= 1.08;
        x.lo = y.lo = -a;
        x.hi = y.hi = a;
        SvgPlot p("plot-signal-lissajous", "Lissajous of the analysed periods (1:1)", x, y, 420, SvgPlot::square_height(420));
        // The spread: each bin's least and greatest radius along its mean point's direction.
        const json& ma = liss["a_v"];
        const json& mb = liss["b_v"];
        json ox = json::array(), oy = json::array(), ix = json::array(), iy = json::array();
        for (std::size_t k = 0; k < ma.size() && k < mb.size(); ++k) {
            if (!ma[k].is_number() || !mb[k].is_number() || !liss["r_min_v"][k].is_number()) {
                for (json* j : {&ox, &oy, &ix, &iy}) j->push_back(nullptr);
                continue;
            }
            const double ang = std::atan2(ma[k].get<double>(), mb[k].get<double>());
            const double r0 = liss["r_min_v"][k].get<double>(), r1 = liss["r_max_v"][k].get<double>();
            ox.push_back(r1 * std::cos(ang));
            oy.push_back(r1 * std::sin(ang));
            ix.push_back(r0 * std::cos(ang));
            iy.push_back(r0 * std::sin(ang));
        }
        for (const auto& [rad, text] : rings) {
            json cx = json::array(), cy = json::array();
            for (int i = 0; i <= 128; ++i) {
                cx.push_back(rad * std::cos(kTwoPi * i / 128.0));
                cy.push_back(rad * std::sin(kTwoPi * i / 128.0));
            }
            p.line(cx, cy, text.rfind("spec", 0) == 0 ? "#bf8700" : "#1a7f37", false, 1.0);
        }
        p.line(ox, oy, "#8c959f", true, 0.8);
        p.line(ix, iy, "#8c959f", true, 0.8);
        p.line(mb, ma, kColours[0], true, 1.6);
        p.legend("mean", kColours[0]);
        p.legend("radius min..max", "#8c959f");
        if (!rings.empty()) {
            p.legend("spec", "#bf8700");
            p.legend("mounting", "#1a7f37");
        } else {
            p.note("no interface profile: no tolerance rings");
        }
        h << p.str();
    }
    // The per-period recording against the period index, the bands' edges as lines.
    const json rec = sq.value("recording", json());
    if (rec.is_object() && rec.value("first_period", json::array()).size() > 0) {
        auto band_of = [&](const std::string& metric) {
            for (const auto& m : graded)
                if (m.value("metric", "") == metric) return m.value("band", json::object());
            return json::object();
        };
        struct Trend {
            const char* id;
            const char* title;
            const char* ylabel;
            std::vector<std::array<const char*, 3>> series;  // recording key, band metric, legend
        };
        const Trend trends[] = {{"plot-signal-vpp", "Amplitude per period", "Vpp (V)", {{"vpp_a_v", "signal_vpp_a_v", "A"}, {"vpp_b_v", "signal_vpp_b_v", "B"}}},
                                {"plot-signal-ratio", "A/B ratio per period", "A/B", {{"ab_ratio", "signal_ab_ratio", "A/B"}}},
                                {"plot-signal-phase", "Phase between A and B per period", "phase (deg)", {{"phase_deg", "signal_phase_deg", "B - A"}}},
                                {"plot-signal-tv", "On/off ratio TV per period", "TV (deg)", {{"tv_a_deg", "signal_tv_a_deg", "A"}, {"tv_b_deg", "signal_tv_b_deg", "B"}}}};
        const json& xs = rec["first_period"];
        for (const auto& t : trends) {
            Axis x{"period index"}, y{t.ylabel};
            x.see_all(xs);
            for (const auto& [key, metric, name] : t.series) y.see_all(rec.value(key, json::array()));
            {  // The band's edges are in view (a trend is read against its limits), unless that overflows the scale.
                Axis with_bands = y;
                for (const auto& [key, metric, name] : t.series)
                    for (const char* k : {"spec", "mounting"}) with_bands.see_all(band_of(metric).value(k, json::array()));
                if (std::isfinite(with_bands.hi - with_bands.lo)) y = with_bands;
            }
            x.finish(0);
            if (x.hi <= x.lo) x.hi = x.lo + 1;
            // At least 1 % of the level (or 0.1 of a unit about 0) tall: three-digit ticks stay distinct.
            if (y.hi >= y.lo) {
                const double least = std::max(0.01 * std::max(std::fabs(y.lo), std::fabs(y.hi)), 0.1 * (y.lo <= 0 && y.hi >= 0 ? 1.0 : 0.0));
                if (y.hi - y.lo < least) {
                    const double mid = 0.5 * (y.lo + y.hi);
                    y.lo = mid - least / 2;
                    y.hi = mid + least / 2;
                }
            }
            y.finish();
            SvgPlot p(t.id, t.title, x, y);
            std::size_t i = 0;
            std::vector<std::string> drawn;
            for (const auto& [key, metric, name] : t.series) {
                const json band = band_of(metric);
                for (const char* k : {"spec", "mounting"}) {
                    const json v = band.value(k, json());
                    if (!v.is_array()) continue;
                    for (const auto& e : v)
                        if (e.is_number() && std::find(drawn.begin(), drawn.end(), std::string(k) + e.dump()) == drawn.end()) {
                            drawn.push_back(std::string(k) + e.dump());
                            p.hline(e.get<double>(), std::string(k) + " " + fmt_num(e.get<double>()), std::string(k) == "spec" ? "#bf8700" : "#1a7f37");
                        }
                }
                p.line(xs, rec.value(key, json::array()), kColours[i], false, 1.3);
                p.legend(name, kColours[i]);
                ++i;
            }
            h << p.str();
        }
        // The same against the shaft angle (each period's place along the scale, counted from the
        // run's start, modulo one revolution): a dirty or damaged section of the scale returns at
        // the same angle every turn.
        const json enc = r["scenario"].value("encoder", json());
        const long long lines = enc.is_object() && enc.value("lines_per_rev", json()).is_number_integer() ? enc["lines_per_rev"].get<long long>() : 0;
        const json& pos = rec.value("position_periods", json::array());
        if (lines > 0 && pos.size() == xs.size()) {
            json deg = json::array();
            for (const auto& v : pos) {
                const long long k = ((v.get<long long>() % lines) + lines) % lines;
                deg.push_back(360.0 * (static_cast<double>(k) + 0.5) / static_cast<double>(lines));
            }
            Axis x{"shaft angle from the run's start (deg, " + std::to_string(lines) + " periods a revolution)"}, y{"Vpp (V)"};
            x.lo = 0;
            x.hi = 360;
            y.see_all(rec["vpp_a_v"]);
            y.see_all(rec["vpp_b_v"]);
            {
                Axis with_bands = y;
                for (const char* metric : {"signal_vpp_a_v", "signal_vpp_b_v"})
                    for (const char* k : {"spec", "mounting"}) with_bands.see_all(band_of(metric).value(k, json::array()));
                if (std::isfinite(with_bands.hi - with_bands.lo)) y = with_bands;
            }
            if (y.hi >= y.lo && y.hi - y.lo < 0.01 * std::fabs(y.hi)) {
                const double mid = 0.5 * (y.lo + y.hi), least = 0.01 * std::fabs(y.hi);
                y.lo = mid - least / 2;
                y.hi = mid + least / 2;
            }
            y.finish();
            SvgPlot p("plot-signal-shaft", "Amplitude per period against shaft angle", x, y);
            p.points(deg, rec["vpp_a_v"], kColours[0], 1.6);
            p.points(deg, rec["vpp_b_v"], kColours[1], 1.6);
            p.legend("A", kColours[0]);
            p.legend("B", kColours[1]);
            h << p.str();
        }
        if (rec.value("periods_per_point", 1) > 1)
            h << "<p class=\"muted\">Each point is the mean of " << rec["periods_per_point"].dump() << " periods (the recording keeps at most 2048 points; against the shaft angle a point is placed at its first period's).</p>";
    }
    h << "</div>\n";
    // The recording as a table (folded: up to 2048 rows), the figures per period or bucket.
    if (rec.is_object() && rec.value("first_period", json::array()).size() > 0) {
        static const std::array<std::pair<const char*, const char*>, 11> kCols{{{"first_period", "first period"},
                                                                               {"position_periods", "place (periods)"},
                                                                               {"t_s", "t (s)"},
                                                                               {"vpp_a_v", "Vpp A (V)"},
                                                                               {"vpp_b_v", "Vpp B (V)"},
                                                                               {"ab_ratio", "A/B"},
                                                                               {"phase_deg", "phase (deg)"},
                                                                               {"tv_a_deg", "TV A (deg)"},
                                                                               {"tv_b_deg", "TV B (deg)"},
                                                                               {"offset_a_v", "offset A (V)"},
                                                                               {"offset_b_v", "offset B (V)"}}};
        const std::size_t n = rec["first_period"].size();
        h << "<details id=\"signal-recording\"><summary>Per-period recording as a table (" << n << " rows";
        if (rec.value("periods_per_point", 1) > 1) h << ", each the mean of " << rec["periods_per_point"].dump() << " periods";
        h << ")</summary><div class=\"table-wrap\"><table><tr>";
        for (const auto& [key, title] : kCols)
            if (rec.contains(key)) h << "<th>" << title << "</th>";
        h << "</tr>\n";
        for (std::size_t i = 0; i < n; ++i) {
            h << "<tr>";
            for (const auto& [key, title] : kCols) {
                if (!rec.contains(key)) continue;
                const json& v = rec[key].size() > i ? rec[key][i] : json();
                char b[32] = "";
                if (v.is_number_integer()) std::snprintf(b, sizeof b, "%s", v.dump().c_str());
                else if (v.is_number()) std::snprintf(b, sizeof b, "%.6g", v.get<double>());  // a period's figure to 6 digits
                h << "<td>" << b << "</td>";
            }
            h << "</tr>\n";
        }
        h << "</table></div></details>\n";
    }
    h << "</div>\n";
    return h.str();
}

std::string metric_tables_html(const json& r) {
    std::ostringstream h;
    const auto cells = report_metrics(r);
    std::vector<std::string> lanes;
    for (const auto& e : r.value("estimators", json::array()))
        lanes.push_back(e.is_object() && e.value("label", json()).is_string() ? e["label"].get<std::string>() : std::string("?"));
    auto find = [&](const MetricInfo* m, const std::string& lane) -> const MetricCell* {
        for (const auto& c : cells)
            if (c.info->name == m->name && c.lane == lane) return &c;
        return nullptr;
    };
    auto td = [&](const MetricCell* c, bool with_unit) {
        std::string o = "<td class=\"num m-" + (c ? xml_escape(c->info->name) : std::string()) + "\"";
        if (c && !c->value) return o + " title=\"" + xml_escape(c->why) + "\">not measured</td>";
        o += ">" + (c ? xml_escape(cell_text(*c, with_unit)) : std::string());
        if (c && c->interval_95) o += " <span class=\"iv\">(95 % " + cell_interval(*c) + ")</span>";
        return o + "</td>";
    };
    h << "<h2>Estimators</h2><div class=\"table-wrap\"><table id=\"estimators\"><tr><th>estimator</th>";
    for (const auto* m : summary_metrics())
        h << "<th title=\"" << xml_escape(m->name + ": " + m->description) << "\">" << xml_escape(m->column)
          << (m->unit.empty() ? std::string() : " (" + xml_escape(m->unit) + ")") << "</th>";
    h << "</tr>\n";
    for (const auto& l : lanes) {
        h << "<tr><td>" << xml_escape(l) << "</td>";
        for (const auto* m : summary_metrics()) h << td(find(m, l), false);
        h << "</tr>\n";
    }
    h << "</table></div>\n";
    // The signals' quality, once for the run.
    if (const auto sig = summary_metrics(true); !sig.empty()) {
        h << "<h2>Signal quality</h2><div class=\"table-wrap\"><table id=\"signal\"><tr>";
        for (const auto* m : sig)
            h << "<th title=\"" << xml_escape(m->name + ": " + m->description) << "\">" << xml_escape(m->column)
              << (m->unit.empty() ? std::string() : " (" + xml_escape(m->unit) + ")") << "</th>";
        h << "</tr>\n<tr>";
        for (const auto* m : sig) h << td(find(m, "run"), false);
        h << "</tr>\n</table></div>\n";
    }
    h << signal_section_html(r);
    h << "<h2>All metrics</h2><div class=\"table-wrap\"><table id=\"metrics\"><tr><th>metric</th><th>unit</th>";
    for (const auto& l : lanes) h << "<th>" << xml_escape(l) << "</th>";
    h << "<th>run</th><th>meaning</th></tr>\n";
    for (const auto& m : metric_catalog()) {
        h << "<tr><td><code>" << xml_escape(m.name) << "</code></td><td>" << xml_escape(m.unit) << "</td>";
        for (const auto& l : lanes) h << (m.run_level ? "<td></td>" : td(find(&m, l), false));
        h << (m.run_level ? td(find(&m, "run"), false) : "<td></td>") << "<td>" << xml_escape(m.description) << "</td></tr>\n";
    }
    h << "</table></div>\n";
    return h.str();
}

std::string metrics_text(const json& r) {
    const auto cells = report_metrics(r);
    std::vector<std::string> lanes;
    for (const auto& c : cells)
        if (std::find(lanes.begin(), lanes.end(), c.lane) == lanes.end()) lanes.push_back(c.lane);
    std::ostringstream o;
    for (const auto& l : lanes) {
        o << l << ":\n";
        for (const auto& c : cells) {
            if (c.lane != l) continue;
            char name[40];
            std::snprintf(name, sizeof name, "  %-26s", c.info->name.c_str());
            o << name << (c.value ? cell_text(c, true) : "not measured: " + c.why);
            if (c.interval_95) o << " (95 % " << cell_interval(c) << ")";
            o << "\n";
        }
    }
    return o.str();
}

// A scenario's "calibrate": both passes' captures, the correction, and each lane before and after.
static std::string calibration_section_html(const json& r) {
    const json c = r.value("calibration", json());
    if (!c.is_object()) return "";
    auto num3 = [](const json& v) { return v.is_number() ? fmt_num(v.get<double>()) : std::string("-"); };
    auto str = [](const json& v) { return xml_escape(v.is_string() ? v.get<std::string>() : v.is_null() ? std::string("-") : v.dump()); };
    auto pass = [&](const json& p) {
        if (!p.is_object()) return std::string("-");
        std::string t = "seed " + (p.value("seed", json()).is_number() ? str(p["seed"]) : std::string("not recorded")) + ", device <code>" + str(p.value("device", json())) + "</code>";
        if (p.value("capture", json()).is_string()) t += ", capture <code>" + str(p["capture"]) + "</code>";
        if (p.value("motion", json()).is_object()) t += ", motion <code>" + xml_escape(p["motion"].dump()) + "</code>";
        if (p.value("error_source", json()).is_string()) t += p["error_source"] == "truth" ? ", truth-scored error" : ", self-referenced error";
        return t;
    };
    std::ostringstream h;
    const std::string status = c.value("status", std::string());
    h << "<h2>Calibration: before and after</h2><div id=\"calibration\">\n<p>Lane <code>" << str(c["lane"]) << "</code>: <span id=\"calibration-status\" class=\""
      << (status == "verified" ? "PASS" : "ERROR") << "\">" << xml_escape(status) << "</span>";
    if (c.value("why", json()).is_string()) h << " &mdash; " << str(c["why"]);
    h << "</p>\n<ul><li>computed on the before pass: " << pass(c.value("computed_on", json())) << "</li>\n<li>verified on the after pass: "
      << pass(c.value("verified_on", json())) << "</li>\n";
    if (c.value("correction", json()).is_object()) {
        const json& f = c["correction"]["file"];
        h << "<li>correction <code>" << str(c["correction"]["path"]) << "</code> (sha256 <code>" << str(c["correction"]["sha256"]).substr(0, 16)
          << "&hellip;</code>): " << f.value("table_rad", json::array()).size() << " entries" << (f.contains("lissajous") ? ", Lissajous stage" : "")
          << ", offset " << num3(f.value("offset_rad", json())) << " rad, predicted residual " << num3(c.value("predicted_rms_rad", json())) << " rad rms</li>\n";
    }
    h << "<li>" << str(c.value("limits", json())) << "</li></ul>\n";
    h << "<div class=\"table-wrap\"><table id=\"calibration-lanes\"><tr><th>lane</th><th>error</th><th>rms before (rad)</th><th>rms after (rad)</th>"
         "<th>max before (rad)</th><th>max after (rad)</th><th>per-sample CRB (rad)</th><th>after / CRB</th><th>predicted (rad)</th><th>correction</th></tr>\n";
    for (const auto& l : c.value("lanes", json::array())) {
        const json b = l.value("before", json::object()), a = l.value("after", json());
        const bool has_after = a.is_object();
        const auto src_word = [](const json& p) {
            const json v = p.is_object() ? p.value("error_source", json()) : json();
            return !v.is_string() ? std::string("-") : v == "truth" ? std::string("truth") : std::string("self-referenced");
        };
        const std::string sb = src_word(b), sa = src_word(a);
        const std::string src = !has_after || sa == sb ? sb : sb + " / " + sa;  // before / after when they differ
        const json crb = has_after && a.value("per_sample_crb_rad", json()).is_number() ? a["per_sample_crb_rad"] : b.value("per_sample_crb_rad", json());
        const json cor = l.value("correction", json());
        const std::string applied = !cor.is_object() ? "-" : cor.value("applied", false) ? (str(cor["kind"]) == "external_env" ? std::string("handed to the child (external_env)") : "applied (" + str(cor["kind"]) + ")") : "not applied: " + str(cor.value("why_not", json()));
        h << "<tr><td>" << str(l["label"]) << "</td><td>" << src << "</td><td>"
          << num3(b.value("rms_rad", json())) << "</td><td>" << (has_after ? num3(a.value("rms_rad", json())) : "-") << "</td><td>"
          << num3(b.value("max_abs_rad", json())) << "</td><td>" << (has_after ? num3(a.value("max_abs_rad", json())) : "-") << "</td><td>" << num3(crb)
          << "</td><td>" << (has_after ? num3(a.value("rms_over_crb", json())) : "-") << "</td><td>" << num3(l.value("predicted_rms_rad", json())) << "</td><td>"
          << applied << "</td></tr>\n";
    }
    h << "</table></div>\n";
    // The error harmonics of each lane, before and after (the first 8 orders the passes fitted).
    h << "<div class=\"table-wrap\"><table id=\"calibration-harmonics\"><tr><th>lane</th><th>order</th><th>before (rad)</th><th>after (rad)</th></tr>\n";
    for (const auto& l : c.value("lanes", json::array())) {
        const json hb = l.value("before", json::object()).value("harmonics", json::array());
        const json a = l.value("after", json());
        const json ha = a.is_object() ? a.value("harmonics", json::array()) : json::array();
        for (std::size_t i = 0; i < std::max(hb.size(), ha.size()) && i < 8; ++i) {
            const json& x = i < hb.size() ? hb[i] : ha[i];
            h << "<tr><td>" << str(l["label"]) << "</td><td>" << str(x["order"]) << "x</td><td>" << (i < hb.size() ? num3(hb[i]["amplitude_rad"]) : "-")
              << "</td><td>" << (i < ha.size() ? num3(ha[i]["amplitude_rad"]) : "-") << "</td></tr>\n";
        }
    }
    h << "</table></div>\n";
    const json before = c.value("before", json());
    if (before.is_object())
        h << "<p>The before pass: " << str(before.value("status", json())) << ", verdict " << str(before.value("verdict", json())) << ", seed "
          << str(before.value("seed", json())) << " (its lanes and measurements are in the report's <code>calibration.before</code>).</p>\n";
    h << "</div>\n";
    return h.str();
}

std::string report_html(const json& r) {
    std::ostringstream h;
    // Values for people: 3 significant digits (the JSON and JUnit keep every digit).
    auto num = [](const json& v) { return v.is_number() ? fmt_num(v.get<double>()) : std::string(); };
    const std::string name = r["scenario"].value("name", std::string("run"));
    const std::string verdict = r.value("verdict", std::string("ERROR"));
    h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><title>fringe report " << xml_escape(name) << " "
      << xml_escape(verdict) << "</title>\n<style>body{font-family:sans-serif;margin:1.5em;max-width:1400px;overflow-wrap:break-word}"
      << "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
      << ".PASS{background:#c8f0c8}.MARGINAL{background:#f8e8a0}.FAIL{background:#f4b4b4}.ERROR,.ABORTED{background:#f4b4b4}"
      << ".plots svg{margin:6px;border:1px solid #eee;max-width:calc(100% - 14px);height:auto}"
      // The page fits its window: wide tables scroll inside themselves, long lines wrap.
      << ".table-wrap{max-width:100%;overflow-x:auto}pre{white-space:pre-wrap;overflow-wrap:anywhere}</style></head><body>\n";
    h << "<h1>" << xml_escape(name) << " <span id=\"verdict\" class=\"" << xml_escape(verdict) << "\">" << xml_escape(verdict) << "</span></h1>\n";
    h << "<p>Run <code>" << xml_escape(r.value("id", std::string())) << "</code>, started " << xml_escape(r.value("started_at", std::string()))
      << ", seed " << r["seed"].dump() << ", device <code>" << xml_escape(r["device"].is_object() ? r["device"].value("uri", std::string()) : "")
      << "</code>, " << r["samples"]["processed"].dump() << " of " << r["samples"]["planned"].dump() << " samples, fringe "
      << xml_escape(r.value("fringe_version", std::string())) << ".</p>\n";
    if (r["error"].is_string()) h << "<p class=\"ERROR\"><b>Error:</b> " << xml_escape(r["error"].get<std::string>()) << "</p>\n";
    if (!r.value("warnings", json::array()).empty()) {
        h << "<h2>Warnings</h2><ul id=\"warnings\">\n";
        for (const auto& w : r["warnings"])
            h << "<li><code>" << xml_escape(w.value("code", std::string())) << "</code> " << xml_escape(w.value("message", std::string())) << "</li>\n";
        h << "</ul>\n";
    }
    h << calibration_section_html(r);
    h << "<h2>Measurements</h2><div class=\"table-wrap\"><table id=\"measurements\"><tr><th>estimator</th><th>metric</th><th>value</th><th>unit</th><th>limit</th><th>outcome</th></tr>\n";
    for (const auto& m : r["measurements"]) {
        std::string lim;
        if (m["limit"].contains("min")) lim += "&ge; " + num(m["limit"]["min"]) + " ";
        if (m["limit"].contains("max")) lim += "&le; " + num(m["limit"]["max"]);
        if (!lim.empty() && !m["unit"].get<std::string>().empty()) {
            lim += ' ';
            lim += xml_escape(m["unit"].get<std::string>());
        }
        h << "<tr><td>" << xml_escape(m["estimator"].get<std::string>()) << "</td><td>" << xml_escape(m["metric"].get<std::string>()) << "</td><td>"
          << (m["value"].is_number() ? num(m["value"]) : std::string("not measured"))
          << (interval(m.value("interval_95", json())).empty() ? std::string() : " <span class=\"iv\">(95 % " + interval(m["interval_95"]) + ")</span>")
          << "</td><td>" << xml_escape(m["unit"].get<std::string>()) << "</td><td>" << lim
          << (m.value("implicit", false) ? " (evidence)" : "")
          << (m.value("interface", json()).is_string() && m.value("grade", json()).is_string()
                  ? " (" + xml_escape(m["interface"].get<std::string>()) + ": " + xml_escape(m["grade"].get<std::string>()) + ")"
                  : std::string())
          << "</td><td class=\""
          << xml_escape(m["outcome"].get<std::string>()) << "\">" << xml_escape(m["outcome"].get<std::string>())
          << (m.contains("reason") ? ": " + xml_escape(m["reason"].get<std::string>()) : std::string()) << "</td></tr>\n";
    }
    h << "</table></div>\n";
    h << metric_tables_html(r);
    h << "<h2>Plots</h2><div class=\"plots\">\n";
    const json& tr = r.contains("traces") && r["traces"].is_object() ? r["traces"] : json::object();
    const bool envelope = tr.value("kind", std::string()) == "envelope";
    if (envelope ? tr["t_s"].empty() : (!tr.contains("t_s") || tr["t_s"].empty())) {
        h << "<p>No traces: the run processed no samples.</p>";
    } else if (envelope) {
        h << envelope_plots(tr, r["estimators"], r);
        h << svg_self_reference(r["estimators"]);
        h << svg_bars(r["estimators"]);
    } else {
        h << stride_plots(tr, r["estimators"]);
        h << svg_bars(r["estimators"]);
        h << svg_spectrum(r["estimators"]);
    }
    // The harmonics' figures with their 95 % intervals (the bars above show the amplitudes).
    {
        std::ostringstream t;
        for (const auto& e : r["estimators"]) {
            const json& m = e["metrics"];
            if (!m.is_object() || !m.contains("harmonics") || !m["harmonics"].is_array()) continue;
            const json unc = m.value("uncertainty", json::object());
            for (const auto& x : m["harmonics"]) {
                std::string iv;
                for (const auto& u : unc.value("harmonics", json::array()))
                    if (u.value("order", 0) == x.value("order", 0)) iv = interval(u.value("amplitude_rad", json()));
                t << "<tr><td>" << xml_escape(e["label"].get<std::string>()) << "</td><td>" << x.value("order", 0) << "x</td><td>"
                  << num(sub(x, "amplitude", "rad")) << (iv.empty() ? std::string() : " <span class=\"iv\">(95 % " + iv + ")</span>") << "</td></tr>\n";
            }
        }
        if (!t.str().empty())
            h << "</div>\n<h2>Error harmonics</h2><div class=\"table-wrap\"><table id=\"harmonics\"><tr><th>estimator</th><th>order</th><th>amplitude (rad)</th></tr>\n"
              << t.str() << "</table></div>\n<div class=\"plots\">";
    }
    // dump() escapes every control character inside strings: its own line breaks stay raw.
    std::string scenario = r["scenario"].dump(2, ' ', false, json::error_handler_t::replace), pre;
    for (std::size_t pos = 0; pos <= scenario.size();) {
        const auto nl = std::min(scenario.find('\n', pos), scenario.size());
        pre += xml_escape(scenario.substr(pos, nl - pos)) + (nl < scenario.size() ? "\n" : "");
        pos = nl + 1;
    }
    h << "\n</div>\n<h2>Scenario as run</h2><pre>" << pre << "</pre>\n</body></html>\n";
    return h.str();
}

}  // namespace fringe
