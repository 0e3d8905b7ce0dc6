#include "report_formats.hpp"

#include "text.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
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
      << num(r["wall_s"]) << "\">\n";
    x << "    <properties>\n";
    x << "      <property name=\"run_id\" value=\"" << xml_escape(r.value("id", std::string())) << "\"/>\n";
    x << "      <property name=\"verdict\" value=\"" << xml_escape(r.value("verdict", std::string())) << "\"/>\n";
    x << "      <property name=\"seed\" value=\"" << r["seed"].dump() << "\"/>\n";
    if (r["device"].is_object()) x << "      <property name=\"device\" value=\"" << xml_escape(r["device"].value("uri", std::string())) << "\"/>\n";
    // Preflight and convention warnings: what the verdict was reached under.
    for (const auto& w : r.value("warnings", json::array()))
        x << "      <property name=\"warning\" value=\"" << xml_escape(w.value("code", std::string()) + ": " + w.value("message", std::string())) << "\"/>\n";
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
        if (m["limit"].contains("max")) x << "        <property name=\"max\" value=\"" << num(m["limit"]["max"]) << "\"/>\n";
        if (m["limit"].contains("min")) x << "        <property name=\"min\" value=\"" << num(m["limit"]["min"]) << "\"/>\n";
        x << "        <property name=\"marginal_fraction\" value=\"" << num(m["limit"]["marginal_fraction"]) << "\"/>\n";
        x << "        <property name=\"outcome\" value=\"" << xml_escape(m["outcome"].get<std::string>()) << "\"/>\n";
        if (m.value("implicit", false)) x << "        <property name=\"evidence\" value=\"true\"/>\n";
        if (m.contains("reason")) x << "        <property name=\"reason\" value=\"" << xml_escape(m["reason"].get<std::string>()) << "\"/>\n";
        x << "      </properties>\n";
        const std::string what = est + " " + metric + " = " + (m["value"].is_number() ? num(m["value"]) : std::string("unmeasured")) + " " +
                                 m["unit"].get<std::string>();
        if (m["outcome"] == "FAIL")
            x << "      <failure message=\"" << xml_escape(m.contains("reason") ? what + ": " + m["reason"].get<std::string>() : what + " outside its limit") << "\"/>\n";
        if (m["outcome"] == "ERROR") x << "      <error message=\"" << xml_escape(what + ": the run did not complete") << "\"/>\n";
        x << "    </testcase>\n";
    }
    x << "  </testsuite>\n</testsuites>\n";
    return x.str();
}

namespace {

const char* kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};

// A scatter/line plot as inline SVG. Points with null y are skipped.
std::string svg_plot(const std::string& title, const std::string& xlabel, const std::string& ylabel,
                     const std::vector<std::pair<std::string, std::pair<const json*, const json*>>>& series, bool dots,
                     bool square = false) {
    const double W = square ? 360 : 640, H = 360, L = 70, R = 10, T = 28, B = 40;
    double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
    for (const auto& [name, xy] : series) {
        const json& xs = *xy.first;
        const json& ys = *xy.second;
        for (std::size_t i = 0; i < xs.size() && i < ys.size(); ++i) {
            if (!xs[i].is_number() || !ys[i].is_number()) continue;
            xmin = std::min(xmin, xs[i].get<double>()); xmax = std::max(xmax, xs[i].get<double>());
            ymin = std::min(ymin, ys[i].get<double>()); ymax = std::max(ymax, ys[i].get<double>());
        }
    }
    if (xmin > xmax) { xmin = 0; xmax = 1; ymin = 0; ymax = 1; }
    if (xmax == xmin) xmax = xmin + 1;
    if (ymax == ymin) { ymax += 1e-12 + std::fabs(ymax) * 0.1; ymin -= 1e-12 + std::fabs(ymin) * 0.1; }
    if (square) { const double a = std::max({std::fabs(xmin), std::fabs(xmax), std::fabs(ymin), std::fabs(ymax)}); xmin = ymin = -a; xmax = ymax = a; }
    auto X = [&](double x) { return L + (x - xmin) / (xmax - xmin) * (W - L - R); };
    auto Y = [&](double y) { return H - B - (y - ymin) / (ymax - ymin) * (H - T - B); };
    std::ostringstream s;
    s.precision(5);
    s << "<svg class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H << "\" viewBox=\"0 0 " << W << " " << H << "\">";
    s << "<text x=\"" << W / 2 << "\" y=\"16\" text-anchor=\"middle\" font-weight=\"bold\">" << xml_escape(title) << "</text>";
    s << "<rect x=\"" << L << "\" y=\"" << T << "\" width=\"" << W - L - R << "\" height=\"" << H - T - B << "\" fill=\"none\" stroke=\"#999\"/>";
    s << "<text x=\"" << (L + W - R) / 2 << "\" y=\"" << H - 6 << "\" text-anchor=\"middle\">" << xml_escape(xlabel) << "</text>";
    s << "<text x=\"12\" y=\"" << (T + H - B) / 2 << "\" transform=\"rotate(-90 12 " << (T + H - B) / 2 << ")\" text-anchor=\"middle\">" << xml_escape(ylabel) << "</text>";
    s << "<text x=\"" << L - 4 << "\" y=\"" << T + 10 << "\" text-anchor=\"end\" font-size=\"10\">" << ymax << "</text>";
    s << "<text x=\"" << L - 4 << "\" y=\"" << H - B << "\" text-anchor=\"end\" font-size=\"10\">" << ymin << "</text>";
    s << "<text x=\"" << L << "\" y=\"" << H - B + 12 << "\" font-size=\"10\">" << xmin << "</text>";
    s << "<text x=\"" << W - R << "\" y=\"" << H - B + 12 << "\" text-anchor=\"end\" font-size=\"10\">" << xmax << "</text>";
    int ci = 0;
    for (const auto& [name, xy] : series) {
        const json& xs = *xy.first;
        const json& ys = *xy.second;
        const char* col = kColours[ci++ % 6];
        if (dots) {
            s << "<g fill=\"" << col << "\">";
            for (std::size_t i = 0; i < xs.size() && i < ys.size(); ++i)
                if (xs[i].is_number() && ys[i].is_number())
                    s << "<circle cx=\"" << X(xs[i].get<double>()) << "\" cy=\"" << Y(ys[i].get<double>()) << "\" r=\"1.3\"/>";
            s << "</g>";
        } else {
            s << "<polyline fill=\"none\" stroke=\"" << col << "\" stroke-width=\"1\" points=\"";
            for (std::size_t i = 0; i < xs.size() && i < ys.size(); ++i)
                if (xs[i].is_number() && ys[i].is_number()) s << X(xs[i].get<double>()) << "," << Y(ys[i].get<double>()) << " ";
            s << "\"/>";
        }
        s << "<text x=\"" << L + 8 << "\" y=\"" << T + 14 + 14 * (ci - 1) << "\" fill=\"" << col << "\" font-size=\"11\">" << xml_escape(name) << "</text>";
    }
    s << "</svg>";
    return s.str();
}

std::string svg_bars(const json& estimators) {
    const double W = 640, H = 300, L = 70, B = 40, T = 28;
    double vmax = 0;
    for (const auto& e : estimators)
        for (const auto& h : e["metrics"]["harmonics"]) vmax = std::max(vmax, h["amplitude"]["rad"].get<double>());
    if (vmax <= 0) vmax = 1;
    std::ostringstream s;
    s.precision(4);
    s << "<svg class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H << "\">";
    s << "<text x=\"" << W / 2 << "\" y=\"16\" text-anchor=\"middle\" font-weight=\"bold\">Error harmonics (amplitude, rad)</text>";
    const std::size_t ne = std::max<std::size_t>(estimators.size(), 1);
    const double group = (W - L - 10) / 6.0, bw = group * 0.8 / static_cast<double>(ne);
    s << "<text x=\"12\" y=\"" << T + 10 << "\" font-size=\"10\">" << vmax << "</text>";
    for (int k = 1; k <= 6; ++k)
        s << "<text x=\"" << L + group * (k - 0.5) << "\" y=\"" << H - B + 14 << "\" text-anchor=\"middle\">" << k << "x</text>";
    std::size_t ei = 0;
    for (const auto& e : estimators) {
        const char* col = kColours[ei % 6];
        for (const auto& h : e["metrics"]["harmonics"]) {
            const int k = h["order"].get<int>();
            const double v = h["amplitude"]["rad"].get<double>();
            const double hh = v / vmax * (H - T - B);
            s << "<rect x=\"" << L + group * (k - 1) + group * 0.1 + bw * static_cast<double>(ei) << "\" y=\"" << H - B - hh << "\" width=\"" << bw
              << "\" height=\"" << hh << "\" fill=\"" << col << "\"><title>" << xml_escape(e["label"].get<std::string>()) << " " << k << "x: " << v
              << " rad</title></rect>";
        }
        s << "<text x=\"" << L + 8 << "\" y=\"" << T + 14 + 14 * ei << "\" fill=\"" << col << "\" font-size=\"11\">" << xml_escape(e["label"].get<std::string>()) << "</text>";
        ++ei;
    }
    s << "</svg>";
    return s.str();
}

}  // namespace

std::string report_html(const json& r) {
    std::ostringstream h;
    const std::string name = r["scenario"].value("name", std::string("run"));
    const std::string verdict = r.value("verdict", std::string("ERROR"));
    h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>fringe report " << xml_escape(name) << " "
      << xml_escape(verdict) << "</title>\n<style>body{font-family:sans-serif;margin:1.5em;max-width:1400px}"
      << "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
      << ".PASS{background:#c8f0c8}.MARGINAL{background:#f8e8a0}.FAIL{background:#f4b4b4}.ERROR,.ABORTED{background:#f4b4b4}"
      << ".plots svg{margin:6px;border:1px solid #eee}</style></head><body>\n";
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
    h << "<h2>Measurements</h2><table id=\"measurements\"><tr><th>estimator</th><th>metric</th><th>value</th><th>unit</th><th>limit</th><th>outcome</th></tr>\n";
    for (const auto& m : r["measurements"]) {
        std::string lim;
        if (m["limit"].contains("min")) lim += "&ge; " + num(m["limit"]["min"]) + " ";
        if (m["limit"].contains("max")) lim += "&le; " + num(m["limit"]["max"]);
        h << "<tr><td>" << xml_escape(m["estimator"].get<std::string>()) << "</td><td>" << xml_escape(m["metric"].get<std::string>()) << "</td><td>"
          << (m["value"].is_number() ? num(m["value"]) : std::string("not measured")) << "</td><td>" << xml_escape(m["unit"].get<std::string>()) << "</td><td>" << lim
          << (m.value("implicit", false) ? " (evidence)" : "") << "</td><td class=\""
          << xml_escape(m["outcome"].get<std::string>()) << "\">" << xml_escape(m["outcome"].get<std::string>())
          << (m.contains("reason") ? ": " + xml_escape(m["reason"].get<std::string>()) : std::string()) << "</td></tr>\n";
    }
    h << "</table>\n<h2>Estimators</h2><table><tr><th>estimator</th><th>rms (rad)</th><th>max |e| (rad)</th><th>rms (% period)</th><th>rms (arcsec mech)</th>"
      << "<th>slipped</th><th>scored samples</th><th>scored cycles</th><th>valid</th><th>per-sample CRB (rad)</th><th>PCRB (rad)</th><th>efficiency</th></tr>\n";
    for (const auto& e : r["estimators"]) {
        const auto& m = e["metrics"];
        const auto& b = e["bounds"];
        const json ev = m.value("evidence", json::object());
        auto bget = [&](const char* k) { return b.is_object() && b.contains(k) ? num(b[k]) : std::string(); };
        h << "<tr><td>" << xml_escape(e["label"].get<std::string>()) << "</td><td>" << num(sub(m, "rms", "rad")) << "</td><td>" << num(sub(m, "max_abs", "rad"))
          << "</td><td>" << num(sub(m, "rms", "percent_period")) << "</td><td>" << num(sub(m, "rms", "arcsec_mech")) << "</td><td>" << m["slipped_samples"].dump()
          << "</td><td>" << ev.value("scored_samples", json()).dump() << "</td><td>" << num(ev.value("scored_cycles", json()))
          << "</td><td>" << (ev.value("valid_fraction", json()).is_number() ? num(100.0 * ev["valid_fraction"].get<double>()) + " %" : std::string())
          << "</td><td>" << bget("per_sample_crb_rad") << "</td><td>" << bget("pcrb_rad") << "</td><td>" << bget("efficiency") << "</td></tr>\n";
    }
    h << "</table>\n<h2>Plots</h2><div class=\"plots\">\n";
    const auto& tr = r.contains("traces") ? r["traces"] : json::object();
    if (!tr.contains("t_s") || tr["t_s"].empty()) {
        h << "<p>No traces: the run processed no samples.</p>";
    } else {
        h << svg_plot("Lissajous (ADC input)", "cos (V)", "sin (V)", {{"input", {&tr["cos_v"], &tr["sin_v"]}}}, true, true);
        std::vector<std::pair<std::string, std::pair<const json*, const json*>>> by_angle, by_time;
        for (const auto& [label, errs] : tr["error_rad"].items()) {
            by_angle.push_back({label, {&tr["theta_true_wrapped_rad"], &errs}});
            by_time.push_back({label, {&tr["t_s"], &errs}});
        }
        h << svg_plot("Error vs electrical angle", "electrical angle (rad)", "error (rad)", by_angle, true);
        h << svg_plot("Error vs time", "time (s)", "error (rad)", by_time, false);
        h << svg_bars(r["estimators"]);
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
