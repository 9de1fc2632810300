#include "adapters/report_html/report_html.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <system_error>

#include <fmt/format.h>

#include "adapters/opencv/image_io.h"
#include "adapters/project_io/text_file.h"
#include "adapters/report_html/label_layout.h"
#include "pipeline/core/error.h"
#include "pipeline/core/statistics.h"

namespace omm {
namespace {

namespace fs = std::filesystem;

// ------------------------------------------------------------------ text ---

std::string Escape(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&#39;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string Base64(std::string_view bytes) {
  static constexpr char kDigits[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  for (size_t i = 0; i < bytes.size(); i += 3) {
    const size_t n = std::min<size_t>(3, bytes.size() - i);
    std::uint32_t v = 0;
    for (size_t k = 0; k < 3; ++k)
      v = (v << 8) | (k < n ? static_cast<unsigned char>(bytes[i + k]) : 0u);
    for (size_t k = 0; k < 4; ++k) out += k <= n ? kDigits[(v >> (18 - 6 * k)) & 63] : '=';
  }
  return out;
}

// "-" for an absent value.
std::string Number(const std::optional<double>& value, int decimals = 4) {
  return value ? fmt::format("{:.{}f}", *value, decimals) : "&ndash;";
}

std::optional<double> Scaled(const std::optional<double>& value, double scale) {
  return value ? std::optional<double>(*value * scale) : std::nullopt;
}

// Element `axis` of the pair `key` of `object`, times `scale`.
std::string PairElement(const ReportObject& object, const char* key, int axis, double scale,
                        int decimals) {
  const std::optional<Eigen::Vector2d> pair = AsPair(Member(object, key));
  return Number(Scaled(pair ? std::optional<double>((*pair)[axis]) : std::nullopt, scale),
                decimals);
}

// ------------------------------------------------- the report's extras ---

// Any value as escaped text: numbers to 6 significant digits, arrays in
// parentheses, objects as "key value; ...".
std::string Text(const ReportValue& value) {
  return std::visit(
      [](const auto& v) -> std::string {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, std::nullptr_t>) {
          return "&ndash;";
        } else if constexpr (std::is_same_v<T, bool>) {
          return v ? "yes" : "no";
        } else if constexpr (std::is_same_v<T, std::int64_t>) {
          return std::to_string(v);
        } else if constexpr (std::is_same_v<T, double>) {
          return fmt::format("{:.6g}", v);
        } else if constexpr (std::is_same_v<T, std::string>) {
          return Escape(v);
        } else if constexpr (std::is_same_v<T, ReportValue::Array>) {
          std::string out = "(";
          for (size_t i = 0; i < v.size(); ++i) out += (i ? ", " : "") + Text(v[i]);
          return out + ")";
        } else {
          std::string out;
          for (const auto& [key, item] : v)
            out += (out.empty() ? "" : "; ") + Escape(key) + " " + Text(item);
          return out;
        }
      },
      value.data());
}

std::string Text(const ReportValue* value) { return value ? Text(*value) : "&ndash;"; }

std::string NumberOf(const ReportObject& object, std::string_view key, int decimals = 4) {
  return Number(AsNumber(Member(object, key)), decimals);
}

// --------------------------------------------------------------- tables ---

// An HTML table; cells are HTML already (escaped by the caller). `align`
// has one letter per column: 'r' right-aligns it (numbers), else left.
class Table {
 public:
  Table(std::vector<std::string> header, std::string align)
      : header_(std::move(header)), align_(std::move(align)) {
    align_.resize(header_.size(), 'l');
  }
  void Row(std::vector<std::string> cells, const std::string& css_class = "") {
    rows_.emplace_back(std::move(cells), css_class);
  }
  std::string Html(const std::string& id) const {
    std::string out = "<table id=\"" + id + "\">\n<thead><tr>";
    for (size_t i = 0; i < header_.size(); ++i)
      out += (align_[i] == 'r' ? "<th class=\"r\">" : "<th>") + header_[i] + "</th>";
    out += "</tr></thead>\n<tbody>\n";
    for (const auto& [cells, css_class] : rows_) {
      out += css_class.empty() ? "<tr>" : "<tr class=\"" + css_class + "\">";
      for (size_t i = 0; i < cells.size(); ++i)
        out += (i < align_.size() && align_[i] == 'r' ? "<td class=\"r\">" : "<td>") + cells[i] +
               "</td>";
      out += "</tr>\n";
    }
    return out + "</tbody></table>\n";
  }

 private:
  std::vector<std::string> header_;
  std::string align_;
  std::vector<std::pair<std::vector<std::string>, std::string>> rows_;
};

// Two-column key / value table.
class Facts {
 public:
  void Add(const std::string& key, const std::string& value_html) {
    rows_ += "<tr><th>" + key + "</th><td>" + value_html + "</td></tr>\n";
  }
  std::string Html() const { return "<table class=\"facts\">\n" + rows_ + "</table>\n"; }

 private:
  std::string rows_;
};

std::string Missing(const std::string& text) { return "<p class=\"missing\">" + text + "</p>\n"; }

// A table's error cell: empty for none.
std::string ErrorCell(const std::string& error) {
  return error.empty() ? "" : "<span class=\"error\">" + Escape(error) + "</span>";
}

// An SVG document for inlining: from "<svg" on (no XML prolog).
std::string InlineSvg(const std::string& svg) {
  const size_t at = svg.find("<svg");
  return at == std::string::npos ? "" : "<div class=\"plot\">" + svg.substr(at) + "</div>\n";
}

constexpr const char* kStyle = R"(
body { font-family: sans-serif; font-size: 14px; margin: 1.5em; color: #222; max-width: 1250px; }
h1 { font-size: 1.5em; } h2 { font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #ccc; }
h3 { font-size: 1.05em; margin-top: 1.2em; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 2px 8px; text-align: left; vertical-align: top; }
th { background: #f0f0f0; } .r { text-align: right; }
table.facts th { font-weight: normal; color: #555; }
tr.beyond td { background: #fdd; font-weight: bold; }
tr.failed td { background: #f3f3f3; color: #777; }
.error { color: #b00; }
p.missing { color: #777; font-style: italic; }
.plot svg { max-width: 100%; height: auto; }
svg.mosaic { width: 100%; max-width: 1200px; height: auto; max-height: 1000px; }
)";

// ------------------------------------------------------------ sections ---

// A value for a facts table: an object as a facts table of its own (one row
// per member, nested objects likewise), anything else as Text.
std::string FactHtml(const ReportValue& value) {
  const ReportObject* object = AsObject(&value);
  if (object == nullptr || object->empty()) return Text(value);
  Facts facts;
  for (const auto& [key, member] : *object) facts.Add(Escape(key), FactHtml(member));
  return facts.Html();
}

// The report's member that the measure stage writes beside the contract's.
constexpr const char* kMeasureKey = "measure";

std::string HeaderSection(const Report& report) {
  std::string out = "<h1>omm report: " + Escape(report.project) + "</h1>\n";
  Facts facts;
  facts.Add("project", Escape(report.project));
  facts.Add("report format", Escape(report.format));
  facts.Add("omm version", Escape(report.software_version));
  facts.Add("inputs SHA-256", "<code>" + Escape(report.inputs_sha256) + "</code>");
  // The measure stage's section has its own place (MeasureStageSection).
  for (const auto& [key, value] : report.extra)
    if (key != kMeasureKey) facts.Add(Escape(key), FactHtml(value));
  return out + facts.Html();
}

// A measurement's row is highlighted when its deviation from the CMM value is
// beyond 3 sigma: the stage's flag, else |JudgedDeviationSigma| > 3.
bool Beyond3Sigma(const MeasurementReport& m) {
  if (const auto flag = AsBool(Member(m.extra, "beyond_3_sigma"))) return *flag;
  const std::optional<double> z = JudgedDeviationSigma(m);
  return z && std::abs(*z) > 3.0;
}

// " Largest part: table for 7, edges for 4." (most first, ties by name), and where the
// table's is the largest for some and no plate on the part gave the mosaic
// a scale, what would.
std::string LargestSourcesSentence(const Report& report,
                                   const std::map<std::string, int>& largest_counts) {
  if (largest_counts.empty()) return "";
  std::vector<std::pair<std::string, int>> counts(largest_counts.begin(), largest_counts.end());
  std::stable_sort(counts.begin(), counts.end(),
                   [](const auto& a, const auto& b) { return a.second > b.second; });
  std::string out = " Largest part:";
  for (size_t i = 0; i < counts.size(); ++i)
    out += fmt::format("{} {} for {}", i ? "," : "", Escape(counts[i].first), counts[i].second);
  out += ".";
  const bool table_largest = largest_counts.count("table") > 0;
  if (table_largest && report.mosaic &&
      AsString(Member(report.mosaic->extra, "plate_scale_check"))) {
    out +=
        " The table's part is, over long distances, the scale that table.csv's positions alone "
        "give the mosaic (see Mosaic registration, scale reference): project.yaml's calibration "
        "plate lying flat on the part, seen whole in a tile, would measure the scale itself.";
  }
  return out;
}

std::string MeasurementsSection(const Report& report) {
  std::string out = "<h2 id=\"measurements\">Measurements</h2>\n";
  if (!report.measurements) return out + Missing("The measure stage has not run.");
  if (report.measurements->empty()) return out + Missing("project.yaml lists no measurements.");
  // The CMM's sigma and the deviation against both, where cmm.csv states it.
  const std::vector<MeasurementReport>& measurements = *report.measurements;
  const bool with_cmm_sigma =
      std::any_of(measurements.begin(), measurements.end(),
                  [](const MeasurementReport& m) { return m.cmm_sigma_mm.has_value(); });
  std::vector<std::string> columns = {"measurement",      "type",   "value mm",
                                      "1-sigma mm",       "CMM mm", "deviation mm",
                                      "deviation / sigma"};
  if (with_cmm_sigma) {
    columns.insert(columns.begin() + 5, "CMM 1-sigma mm");
    columns.push_back("deviation / both sigmas");
  }
  columns.insert(columns.end(), {"1-sigma by source, mm", "error"});
  Table table(columns, with_cmm_sigma ? "llrrrrrrrll" : "llrrrrrll");
  int beyond = 0, failed = 0;
  std::map<std::string, int> largest_counts;  // measurements per largest source of sigma
  for (const MeasurementReport& m : measurements) {
    std::string sources, largest;
    double largest_mm = 0.0;
    if (const ReportObject* breakdown = AsObject(Member(m.extra, "sigma_breakdown_mm"))) {
      for (const auto& [source, value] : *breakdown) {
        const std::optional<double> mm = AsNumber(&value);
        sources += (sources.empty() ? "" : ", ") + Escape(source) + " " + Number(mm);
        if (mm && *mm > largest_mm) {
          largest_mm = *mm;
          largest = source;
        }
      }
    }
    if (m.value_mm && !largest.empty()) ++largest_counts[largest];
    std::string css_class;
    if (!m.value_mm) {
      css_class = "failed";
      ++failed;
    } else if (Beyond3Sigma(m)) {
      css_class = "beyond";
      ++beyond;
    }
    std::vector<std::string> cells = {Escape(m.name),
                                      MeasurementTypeName(m.type),
                                      Number(m.value_mm),
                                      Number(m.sigma_mm),
                                      Number(m.cmm_mm),
                                      Number(m.deviation_mm),
                                      Number(m.deviation_sigma, 2)};
    if (with_cmm_sigma) {
      cells.insert(cells.begin() + 5, Number(m.cmm_sigma_mm));
      cells.push_back(Number(m.deviation_combined_sigma, 2));
    }
    cells.insert(cells.end(), {sources.empty() ? "&ndash;" : sources, ErrorCell(m.error)});
    table.Row(cells, css_class);
  }
  out += fmt::format(
      "<p>{} measurement(s): {} made, {} failed, {} beyond 3 sigma of the CMM "
      "value (highlighted{}). The 1-sigma by source are independent parts whose squares sum to "
      "the 1-sigma's: the calibration images' noise, the registration's (the tiles' matches and "
      "plate marks), the table positions' errors and the edge fits'.",
      measurements.size(), measurements.size() - failed, failed, beyond,
      with_cmm_sigma ? "; where cmm.csv states the CMM's 1-sigma, of omm's and the CMM's combined"
                     : "");
  out += LargestSourcesSentence(report, largest_counts);
  return out + "</p>\n" + table.Html("measurements-table");
}

// The measure stage's own facts (report.json's `measure`), its known members
// in words, any other as FactHtml.
std::string MeasureStageSection(const Report& report) {
  const ReportObject* measure = AsObject(Member(report.extra, kMeasureKey));
  if (measure == nullptr) return "";
  Facts facts;
  for (const auto& [key, value] : *measure) {
    if (key == "brief") {
      facts.Add("summary", Text(value));
    } else if (key == "intrinsics_refined" && AsBool(&value)) {
      facts.Add("intrinsics",
                *AsBool(&value) ? "refined by the mosaic's adjustment, the calibration their prior"
                                : "as calibrated");
    } else if (const ReportObject* bore = AsObject(&value); key == "bore_prior" && bore) {
      // Small holes near the camera's axis borrow their bore's shape from
      // the others (pipeline/measure/README.md).
      const std::string views = fmt::format(
          "{} views gave the bottom rim's scale, {} the wall's contrast",
          Text(Member(*bore, "views_with_k")), Text(Member(*bore, "views_with_wall_level")));
      facts.Add(
          "bore prior (small holes near the axis)",
          Member(*bore, "bottom_rim_scale")
              ? fmt::format("bottom rim at {} of the top rim's scale, wall contrast {} &plusmn; "
                            "{} ({})",
                            NumberOf(*bore, "bottom_rim_scale"), NumberOf(*bore, "wall_contrast"),
                            NumberOf(*bore, "wall_contrast_sigma"), views)
              : "none: too few views (" + views + ")");
    } else if (key == "views_gsd_mm" && AsNumber(&value)) {
      facts.Add("grid of the holes' fits", Text(value) + " mm/px");
    } else if (key == "seconds" && AsNumber(&value)) {
      facts.Add("run time", NumberOf(*measure, key, 2) + " s");
    } else {
      facts.Add(Escape(key), FactHtml(value));
    }
  }
  return "<h3 id=\"measure-stage\">Measure stage</h3>\n" + facts.Html();
}

std::string FeaturesSection(const Report& report) {
  std::string out = "<h3 id=\"features\">Features (part frame)</h3>\n";
  if (!report.features)
    return out + Missing("No features located (the measure stage has not run).");
  if (report.features->empty()) return out + Missing("project.yaml lists no features.");
  Table table({"feature", "type", "centre x mm", "centre y mm", "diameter mm", "1-sigma x mm",
               "1-sigma y mm", "1-sigma diameter mm", "error"},
              "llrrrrrrl");
  for (const FeatureReport& f : *report.features) {
    auto coordinate = [](const std::optional<Eigen::Vector2d>& v, int axis) {
      return v ? std::optional<double>((*v)(axis)) : std::nullopt;
    };
    table.Row({Escape(f.name), FeatureTypeName(f.type), Number(coordinate(f.centre_mm, 0)),
               Number(coordinate(f.centre_mm, 1)), Number(f.diameter_mm),
               Number(coordinate(f.centre_sigma_mm, 0)), Number(coordinate(f.centre_sigma_mm, 1)),
               Number(f.diameter_sigma_mm), ErrorCell(f.error)},
              f.centre_mm ? "" : "failed");
  }
  return out + table.Html("features-table");
}

std::string MosaicFigure(const Report& report, const ReportHtmlInputs& inputs) {
  std::string out = "<h2 id=\"mosaic-figure\">Mosaic with the measured features</h2>\n";
  if (!report.mosaic) return out + Missing("The mosaic stage has not run.");
  const MosaicReport& mosaic = *report.mosaic;
  if (inputs.mosaic_png.empty()) {
    return out + Missing("No mosaic image: " + Escape(inputs.mosaic_missing_why));
  }
  const double w = mosaic.size_px.x(), h = mosaic.size_px.y(), gsd = mosaic.gsd_mm;
  if (w <= 0 || h <= 0 || gsd <= 0) {
    return out + Missing("The report's mosaic section has no size or gsd.");
  }
  // Part frame (mm) to the overlay's user space (see the header).
  auto to_svg = [&](const Eigen::Vector2d& part_mm) {
    return Eigen::Vector2d((part_mm.x() - mosaic.origin_mm.x()) / gsd,
                           (mosaic.origin_mm.y() - part_mm.y()) / gsd);
  };
  // User units per screen pixel: the figure is laid out at most 1200 px
  // wide and 1000 px high (the style sheet's svg.mosaic), so labels keep
  // their size in tall mosaics too.
  const double unit = std::max(w / 1200.0, h / 1000.0);
  std::string svg = fmt::format(
      "<svg class=\"mosaic\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {0:g} {1:g}\" "
      "font-family=\"sans-serif\" font-size=\"{2:.2f}\">\n"
      "<image x=\"0\" y=\"0\" width=\"{0:g}\" height=\"{1:g}\" preserveAspectRatio=\"none\" "
      "href=\"data:image/png;base64,{3}\"/>\n",
      w, h, 14 * unit, Base64(inputs.mosaic_png));
  // Shapes first, then the labels over them, each placed where it covers
  // no other label (label_layout.h): features' names first, then distances.
  const double font_size = 14 * unit, halo = 3 * unit;
  struct Label {
    const char* css_class;
    const char* colour;
    std::string text;  // escaped
    std::vector<Eigen::AlignedBox2d> candidates;
  };
  std::vector<Label> labels;
  // A label's box: its ink (DejaVu Sans: ascent 0.93 em, descent 0.24 em)
  // and its halo, half of which lies outside the glyphs, plus a unit.
  const double pad = halo / 2 + unit, label_h = 1.17 * font_size + 2 * pad;
  auto label_w = [&](std::string_view raw) { return TextWidthEstimate(raw, font_size) + 2 * pad; };
  std::map<std::string, Eigen::Vector2d> centres;  // features found, user space
  std::string not_found;
  if (report.features) {
    for (const FeatureReport& f : *report.features) {
      if (!f.centre_mm) {
        not_found += (not_found.empty() ? "" : ", ") + Escape(f.name);
        // Where it was looked for (near_px through the scene, omm's pixel
        // convention): a dashed mark, so that a reader finds the place.
        if (const std::optional<Eigen::Vector2d> px =
                AsPair(Member(f.extra, "expected_mosaic_px"))) {
          const Eigen::Vector2d c = *px + Eigen::Vector2d(0.5, 0.5);
          const double r = 10 * unit;
          svg += fmt::format(
              "<g class=\"not-found\"><circle cx=\"{:.3f}\" cy=\"{:.3f}\" r=\"{:.3f}\" "
              "fill=\"none\" stroke=\"#d00000\" stroke-width=\"2\" stroke-dasharray=\"4 3\" "
              "vector-effect=\"non-scaling-stroke\"/></g>\n",
              c.x(), c.y(), r);
          const std::string raw = f.name + " (not found)";
          labels.push_back({"not-found-label", "#d00000", Escape(raw),
                            CircleLabelCandidates(c, r, unit, label_w(raw), label_h)});
        }
        continue;
      }
      const Eigen::Vector2d c = to_svg(*f.centre_mm);
      centres[f.name] = c;
      const double r = f.diameter_mm ? *f.diameter_mm / 2 / gsd : 6 * unit;
      svg += fmt::format(
          "<g class=\"feature\"><circle cx=\"{:.3f}\" cy=\"{:.3f}\" r=\"{:.3f}\" fill=\"none\" "
          "stroke=\"#ff2a6d\" stroke-width=\"2\" vector-effect=\"non-scaling-stroke\"/></g>\n",
          c.x(), c.y(), r);
      labels.push_back({"feature-label", "#ff2a6d", Escape(f.name),
                        CircleLabelCandidates(c, r, unit, label_w(f.name), label_h)});
    }
  }
  std::map<std::string, const MeasurementReport*> values;
  if (report.measurements) {
    for (const MeasurementReport& m : *report.measurements) values[m.name] = &m;
  }
  for (const MeasurementSpec& spec : inputs.measurements) {
    if (spec.type != MeasurementType::kDistance || spec.features.size() != 2) continue;
    const auto a = centres.find(spec.features[0]), b = centres.find(spec.features[1]);
    if (a == centres.end() || b == centres.end()) continue;
    std::string raw = spec.name;
    if (const auto m = values.find(spec.name); m != values.end() && m->second->value_mm) {
      raw += fmt::format(" {:.4f}", *m->second->value_mm);
      if (m->second->sigma_mm) raw += fmt::format(" \u00b1 {:.4f}", *m->second->sigma_mm);
      raw += " mm";
    }
    svg += fmt::format(
        "<g class=\"distance\"><line x1=\"{:.3f}\" y1=\"{:.3f}\" x2=\"{:.3f}\" y2=\"{:.3f}\" "
        "stroke=\"#05d9e8\" stroke-width=\"1.5\" vector-effect=\"non-scaling-stroke\"/></g>\n",
        a->second.x(), a->second.y(), b->second.x(), b->second.y());
    labels.push_back({"distance-label", "#005f73", Escape(raw),
                      SegmentLabelCandidates(a->second, b->second, unit, label_w(raw), label_h)});
  }
  std::vector<std::vector<Eigen::AlignedBox2d>> candidates;
  for (const Label& label : labels) candidates.push_back(label.candidates);
  const std::vector<int> chosen =
      PlaceLabels(candidates, Eigen::AlignedBox2d(Eigen::Vector2d::Zero(), Eigen::Vector2d(w, h)));
  svg += fmt::format(
      "<g class=\"labels\" stroke=\"white\" stroke-width=\"{:.2f}\" paint-order=\"stroke\">\n",
      halo);
  for (size_t i = 0; i < labels.size(); ++i) {
    const Eigen::AlignedBox2d& box = labels[i].candidates[chosen[i]];
    svg += fmt::format("<text class=\"{}\" x=\"{:.3f}\" y=\"{:.3f}\" fill=\"{}\">{}</text>\n",
                       labels[i].css_class, box.min().x() + pad,
                       box.max().y() - pad - 0.24 * font_size, labels[i].colour, labels[i].text);
  }
  svg += "</g>\n";
  svg += "</svg>\n";
  out += "<figure>" + svg + "<figcaption>";
  out += fmt::format(
      "{:g} x {:g} px at {:g} mm/px, top-left outer corner at part ({:g}, {:g}) "
      "mm; columns along +X, rows along -Y. ",
      w, h, gsd, mosaic.origin_mm.x(), mosaic.origin_mm.y());
  if (!report.features) out += "No features drawn: the measure stage has not run.";
  if (!not_found.empty()) out += "Not found: " + not_found + ".";
  return out + "</figcaption></figure>\n";
}

std::string CalibrationSection(const Report& report, const ReportHtmlInputs& inputs) {
  std::string out = "<h2 id=\"calibration\">Calibration</h2>\n";
  if (!report.calibration) return out + Missing("The calibrate stage has not run.");
  const CalibrationReport& c = *report.calibration;
  const ReportObject& extra = c.extra;
  Facts facts;
  if (const std::string* source = AsString(Member(extra, "source")))
    facts.Add("source", Escape(*source));
  facts.Add("lens model", Escape(c.lens_model));
  if (const ReportObject* choice = AsObject(Member(extra, "lens_model_choice"))) {
    facts.Add("why this lens model", Text(Member(*choice, "why")));
  }
  if (AsBool(Member(extra, "rms_px_known")) == false) {
    facts.Add("rms residual", "unknown (camera model file, no solve)");
  } else {
    facts.Add("rms residual", fmt::format("{:.4f} px", c.rms_px));
    if (const auto weighted = AsNumber(Member(extra, "weighted_rms")))
      facts.Add("rms of the weighted residuals (mrcal)", fmt::format("{:.4f}", *weighted));
    facts.Add("images used", std::to_string(c.images_used));
    facts.Add("images rejected", std::to_string(c.images_rejected.size()));
  }
  if (const auto outliers = AsNumber(Member(extra, "num_outliers")))
    facts.Add("outlier marks", fmt::format("{:g}", *outliers));
  if (const ReportObject* u = AsObject(Member(extra, "projection_uncertainty"))) {
    if (AsBool(Member(*u, "included")).value_or(false)) {
      facts.Add("projection uncertainty (worst-direction 1-sigma)",
                fmt::format("{} px typical (median over the imager), {} px worst, at {} mm",
                            NumberOf(*u, "typical_px"), NumberOf(*u, "worst_px"),
                            NumberOf(*u, "distance_mm", 0)));
    } else {
      facts.Add("projection uncertainty", "not included: " + Text(Member(*u, "why_not")));
    }
  }
  if (const std::string* brief = AsString(Member(extra, "brief")))
    facts.Add("summary", Escape(*brief));
  out += facts.Html();

  out += "<h3>Images rejected</h3>\n";
  if (c.images_rejected.empty()) {
    out += "<p>None.</p>\n";
  } else {
    Table rejected({"image", "why"}, "ll");
    for (const RejectedImage& r : c.images_rejected) rejected.Row({Escape(r.image), Escape(r.why)});
    out += rejected.Html("rejected-table");
  }
  if (const ReportValue::Array* per_image = AsArray(Member(extra, "per_image"))) {
    out += "<h3>Residuals per image</h3>\n";
    Table table({"image", "rms px", "inlier marks", "outlier marks"}, "lrrr");
    for (const ReportValue& row : *per_image) {
      const ReportObject* r = AsObject(&row);
      if (r == nullptr) continue;
      table.Row({Text(Member(*r, "image")), NumberOf(*r, "rms_px"), Text(Member(*r, "inliers")),
                 Text(Member(*r, "outliers"))});
    }
    out += table.Html("per-image-table");
  }
  out += "<h3>Residuals</h3>\n";
  out +=
      inputs.residuals_svg.empty() ? Missing("No residual plot.") : InlineSvg(inputs.residuals_svg);
  out += "<h3>Projection uncertainty over the imager</h3>\n";
  out += inputs.uncertainty_svg.empty() ? Missing("No uncertainty map.")
                                        : InlineSvg(inputs.uncertainty_svg);
  if (!inputs.study_svg.empty()) {
    out += "<h3>Image-count study</h3>\n";
    if (const ReportObject* study = AsObject(Member(extra, "study")))
      out += "<p>" + Text(Member(*study, "brief")) + "</p>\n";
    out += InlineSvg(inputs.study_svg);
  }
  return out;
}

// Where the table scatters significantly less than table.sigma_mm (below
// the chi-square's 0.1 % quantile): said, not acted on. The sigmas keep the
// stated sigma, which may hold what the scatter cannot show (a scale error
// common to every position); a smaller one would make them smaller.
std::string ScatterFarBelowStated(const ReportObject& table) {
  const std::optional<double> estimated = AsNumber(Member(table, "estimated_mm"));
  const std::optional<double> stated = AsNumber(Member(table, "stated_mm"));
  const std::optional<double> redundancy = AsNumber(Member(table, "redundancy"));
  if (!estimated || !stated || !redundancy || !(*stated > 0.0) || !(*redundancy >= 1.0)) return "";
  const double ratio = *estimated / *stated;
  const int dof = static_cast<int>(std::lround(*redundancy));
  if (!(*redundancy * ratio * ratio < ChiSquareQuantile(0.001, dof))) return "";
  return fmt::format(
      "; the positions scatter {:.1f} times less than table.sigma_mm, which the sigmas' table "
      "parts keep (a scale error common to every position would not show in the scatter)",
      1.0 / ratio);
}

// The mosaic's facts: its grid, the registration's summary, the scale and
// the checks on the table and the working distance.
std::string MosaicFacts(const MosaicReport& m) {
  const ReportObject& extra = m.extra;
  Facts facts;
  facts.Add("rms reprojection residual", fmt::format("{:.4f} px", m.rms_px));
  facts.Add("file", Escape(m.file));
  facts.Add("size",
            fmt::format("{} x {} px at {:g} mm/px", m.size_px.x(), m.size_px.y(), m.gsd_mm));
  facts.Add("origin (outer corner of pixel (0, 0))",
            fmt::format("({:g}, {:g}) mm", m.origin_mm.x(), m.origin_mm.y()));
  if (Member(extra, "plane_tilt_deg"))
    facts.Add("plane tilt", NumberOf(extra, "plane_tilt_deg", 4) + " deg");
  if (Member(extra, "num_tracks")) facts.Add("tracks", Text(Member(extra, "num_tracks")));
  if (const std::string* brief = AsString(Member(extra, "brief")))
    facts.Add("summary", Escape(*brief));
  // The metric scale: the plate on the part, or the table alone.
  const ReportValue* plate = Member(extra, "plate_scale_check");
  if (const std::string* text = AsString(plate)) facts.Add("scale reference", Escape(*text));
  if (const ReportObject* check = AsObject(plate)) {
    std::string line = Text(Member(*check, "brief"));
    if (Member(*check, "scale_minus_1_ppm") != nullptr) {
      line +=
          fmt::format("; the table's scale against the plate {} &plusmn; {} ppm",
                      NumberOf(*check, "scale_minus_1_ppm", 1), NumberOf(*check, "sigma_ppm", 1));
    }
    facts.Add("scale reference", line);
  }
  if (Member(extra, "scale_sigma_ppm") != nullptr)
    facts.Add("scale 1-sigma", NumberOf(extra, "scale_sigma_ppm", 1) + " ppm");
  if (const ReportObject* table = AsObject(Member(extra, "table_sigma_check"))) {
    const bool consistent = AsBool(Member(*table, "consistent")).value_or(true);
    facts.Add("table positions' scatter about the features",
              NumberOf(*table, "estimated_mm", 4) + " mm against table.sigma_mm " +
                  NumberOf(*table, "stated_mm", 4) + " mm (" + NumberOf(*table, "redundancy", 1) +
                  " dof): " +
                  (consistent ? "consistent" + ScatterFarBelowStated(*table)
                   : Member(*table, "used_mm") != nullptr
                       ? "<b>too large: the priors are weighed by, and the sigmas' table parts "
                         "assume, " +
                             NumberOf(*table, "used_mm", 4) +
                             " mm; check table.sigma_mm and table.csv</b>"
                       // reports before used_mm: the stated sigma was kept
                       : "<b>too large: the sigmas' table parts assume table.sigma_mm; check "
                         "it and table.csv</b>"));
  }
  if (const ReportObject* distance = AsObject(Member(extra, "working_distance_check"))) {
    const bool consistent = AsBool(Member(*distance, "consistent")).value_or(true);
    facts.Add("part's distance from the camera",
              NumberOf(*distance, "part_mm", 0) + " mm; the calibration plate's " +
                  NumberOf(*distance, "calibration_min_mm", 0) + "-" +
                  NumberOf(*distance, "calibration_max_mm", 0) + " mm" +
                  (consistent ? "" : ": <b>far from it: are table.csv's positions in mm?</b>"));
  }
  if (const ReportValue::Array* groups = AsArray(Member(extra, "tile_groups"));
      groups && groups->size() > 1) {
    std::string listed;
    for (const ReportValue& group : *groups) {
      std::string names;
      if (const ReportValue::Array* images = AsArray(&group)) {
        for (const ReportValue& image : *images)
          names += (names.empty() ? "" : ", ") + Text(&image);
      }
      listed += (listed.empty() ? "" : "; ") + names;
    }
    facts.Add("tile groups",
              fmt::format("<b>{} groups that nothing seen in two of them ties together</b>: {}. "
                          "table.csv alone places them against each other: every measurement "
                          "between two of them carries its sigma (the table part).",
                          groups->size(), listed));
  }
  if (const ReportObject* exposure = AsObject(Member(extra, "exposure")))
    facts.Add("exposure", Text(Member(*exposure, "brief")));
  return facts.Html();
}

// The tile pairs: candidates, matches, residuals, usable.
std::string PairsTable(const ReportObject& extra) {
  std::string out;
  if (const ReportValue::Array* pairs = AsArray(Member(extra, "pairs"))) {
    out += "<h3>Tile pairs</h3>\n";
    Table table({"tile a", "tile b", "predicted overlap", "candidates", "matched", "inliers",
                 "tag corners", "used", "rms px", "weight (by scatter)", "usable"},
                "llrrrrrrrrl");
    for (const ReportValue& row : *pairs) {
      const ReportObject* p = AsObject(&row);
      if (p == nullptr) continue;
      const ReportValue::Array* images = AsArray(Member(*p, "images"));
      const bool two = images != nullptr && images->size() == 2;
      table.Row({two ? Text((*images)[0]) : "?", two ? Text((*images)[1]) : "?",
                 NumberOf(*p, "predicted_overlap", 2), Text(Member(*p, "candidates")),
                 Text(Member(*p, "matched")), Text(Member(*p, "inliers")),
                 Text(Member(*p, "tag_corners")), Text(Member(*p, "used")), NumberOf(*p, "rms_px"),
                 NumberOf(*p, "weight_scale", 2),
                 Text(Member(*p, "usable")) +
                     (AsBool(Member(*p, "matched_on_adjusted_scene")).value_or(false)
                          ? " (matched on the adjusted scene's prediction)"
                          : "")},
                AsBool(Member(*p, "usable")).value_or(true) ? "" : "failed");
    }
    out += table.Html("pairs-table");
  }
  return out;
}

// The holes that tie the tiles, and those dropped.
std::string HoleTiesTables(const ReportObject& extra) {
  std::string out;
  if (const ReportObject* hole_ties = AsObject(Member(extra, "hole_ties"))) {
    out += "<h3>Holes tying the tiles</h3>\n<p>" + Text(Member(*hole_ties, "brief")) + "</p>\n";
    const ReportValue::Array* ties = AsArray(Member(*hole_ties, "ties"));
    if (ties != nullptr && !ties->empty()) {
      Table table({"feature", "tiles", "rms residual px"}, "llr");
      for (const ReportValue& row : *ties) {
        const ReportObject* tie = AsObject(&row);
        if (tie == nullptr) continue;
        std::string tiles;
        if (const ReportValue::Array* images = AsArray(Member(*tie, "images"))) {
          for (const ReportValue& image : *images)
            tiles += (tiles.empty() ? "" : ", ") + Text(&image);
        }
        table.Row({Text(Member(*tie, "feature")), tiles, NumberOf(*tie, "rms_px")});
      }
      out += table.Html("hole-ties-table");
    }
    const ReportValue::Array* dropped = AsArray(Member(*hole_ties, "dropped"));
    if (dropped != nullptr && !dropped->empty()) {
      std::string names;
      for (const ReportValue& name : *dropped) names += (names.empty() ? "" : ", ") + Text(&name);
      out += "<p>Dropped (their views disagree beyond their sigma): " + names + "</p>\n";
    }
  }
  return out;
}

// The overlaps of held or weakly tied tiles aligned directly.
std::string OverlapTiesTable(const ReportObject& extra) {
  std::string out;
  if (const ReportObject* overlap_ties = AsObject(Member(extra, "overlap_ties"))) {
    const ReportValue::Array* ties = AsArray(Member(*overlap_ties, "ties"));
    if (ties != nullptr && !ties->empty()) {
      out += "<h3>Overlaps aligned directly (held or weakly tied tiles)</h3>\n<p>" +
             Text(Member(*overlap_ties, "brief")) + "</p>\n";
      Table table({"placed tile", "aligned tile", "pixels", "shift x px", "shift y px",
                   "sigma major px", "sigma minor px", "rms residual px", "used"},
                  "llrrrrrrl");
      for (const ReportValue& row : *ties) {
        const ReportObject* tie = AsObject(&row);
        if (tie == nullptr) continue;
        const ReportValue::Array* images = AsArray(Member(*tie, "images"));
        const bool two = images != nullptr && images->size() == 2;
        auto element = [&](const char* key, int axis) {
          return PairElement(*tie, key, axis, 1.0, 3);
        };
        const bool used = AsBool(Member(*tie, "used")).value_or(false);
        table.Row({two ? Text((*images)[0]) : "?", two ? Text((*images)[1]) : "?",
                   Text(Member(*tie, "pixels")), element("shift_px", 0), element("shift_px", 1),
                   element("sigma_px", 0), element("sigma_px", 1), NumberOf(*tie, "rms_px"),
                   used ? "yes" : "no: " + Text(Member(*tie, "why"))},
                  used ? "" : "failed");
      }
      out += table.Html("overlap-ties-table");
    }
  }
  return out;
}

// Each tile's adjusted minus commanded table position.
std::string TilesTable(const ReportObject& extra) {
  std::string out;
  if (const ReportValue::Array* tiles = AsArray(Member(extra, "tiles"))) {
    out += "<h3>Tiles: adjusted minus commanded table position</h3>\n";
    Table table({"tile", "commanded x mm", "commanded y mm", "adjusted - commanded x &#181;m",
                 "adjusted - commanded y &#181;m", "held by prior", "table prior used",
                 "exposure gain", "pixels at full scale %"},
                "lrrrrllrr");
    for (const ReportValue& row : *tiles) {
      const ReportObject* t = AsObject(&row);
      if (t == nullptr) continue;
      table.Row({Text(Member(*t, "image")), PairElement(*t, "commanded_mm", 0, 1.0, 3),
                 PairElement(*t, "commanded_mm", 1, 1.0, 3),
                 PairElement(*t, "adjusted_minus_commanded_mm", 0, 1000.0, 2),
                 PairElement(*t, "adjusted_minus_commanded_mm", 1, 1000.0, 2),
                 Text(Member(*t, "held_by_prior")), Text(Member(*t, "table_prior_used")),
                 NumberOf(*t, "exposure_gain", 4),
                 Number(Scaled(AsNumber(Member(*t, "saturated_fraction")), 100.0), 1)});
    }
    out += table.Html("tiles-table");
  }
  return out;
}

// The table positions the features contradicted, left out.
std::string PriorsLeftOutTable(const ReportObject& extra) {
  std::string out;
  const ReportValue::Array* left_out = AsArray(Member(extra, "table_priors_left_out"));
  if (left_out != nullptr && !left_out->empty()) {
    out +=
        "<h3>Table positions left out</h3>\n<p>The features put these tiles far from their "
        "table.csv positions (w&#178; beyond its bound: chi-square, 2 dof); the adjustment left "
        "those positions out. Check table.csv and the machine.</p>\n";
    Table table({"tile", "adjusted - commanded x &#181;m", "adjusted - commanded y &#181;m",
                 "w&#178;", "bound"},
                "lrrrr");
    for (const ReportValue& row : *left_out) {
      const ReportObject* t = AsObject(&row);
      if (t == nullptr) continue;
      table.Row({Text(Member(*t, "image")),
                 PairElement(*t, "adjusted_minus_commanded_mm", 0, 1000.0, 1),
                 PairElement(*t, "adjusted_minus_commanded_mm", 1, 1000.0, 1),
                 NumberOf(*t, "w2", 1), NumberOf(*t, "bound", 1)});
    }
    out += table.Html("priors-left-out-table");
  }
  return out;
}

// The tiles held by their table prior alone, and why.
std::string HeldTilesTable(const ReportObject& extra) {
  std::string out;
  if (const ReportValue::Array* held = AsArray(Member(extra, "tiles_held_by_prior"))) {
    out += "<h3>Tiles held by the table prior alone</h3>\n";
    if (held->empty()) {
      out += "<p>None: every tile is registered by features.</p>\n";
    } else {
      Table table({"tile", "why"}, "ll");
      for (const ReportValue& row : *held) {
        if (const ReportObject* t = AsObject(&row))
          table.Row({Text(Member(*t, "image")), Text(Member(*t, "why"))});
      }
      out += table.Html("held-table");
    }
  }
  return out;
}

// The exposure compensation, before and after.
std::string ExposureFacts(const ReportObject& extra) {
  std::string out;
  if (const ReportObject* exposure = AsObject(Member(extra, "exposure"))) {
    out += "<h3>Exposure compensation</h3>\n";
    Facts e;
    e.Add("summary", Text(Member(*exposure, "brief")));
    e.Add("relative sigma between tiles, before / after",
          NumberOf(*exposure, "relative_sigma_before") + " / " +
              NumberOf(*exposure, "relative_sigma_after"));
    e.Add("largest step between overlapping tiles, before / after",
          NumberOf(*exposure, "max_pair_step_before") + " / " +
              NumberOf(*exposure, "max_pair_step_after"));
    out += e.Html();
  }
  return out;
}

std::string MosaicSection(const Report& report) {
  std::string out = "<h2 id=\"mosaic\">Mosaic registration</h2>\n";
  if (!report.mosaic) return out + Missing("The mosaic stage has not run.");
  const ReportObject& extra = report.mosaic->extra;
  return out + MosaicFacts(*report.mosaic) + PairsTable(extra) + HoleTiesTables(extra) +
         OverlapTiesTable(extra) + TilesTable(extra) + PriorsLeftOutTable(extra) +
         HeldTilesTable(extra) + ExposureFacts(extra);
}

// The file `name` (relative to out/, as the report names it) in the first of
// `dirs` that holds it; empty if none does or if the name would leave out/.
fs::path FindNamed(const std::string& name, const std::vector<fs::path>& dirs) {
  const fs::path relative(name);
  if (name.empty() || relative.is_absolute() ||
      std::find(relative.begin(), relative.end(), "..") != relative.end()) {
    return {};
  }
  std::error_code ec;
  for (const fs::path& dir : dirs)
    if (fs::is_regular_file(dir / relative, ec)) return dir / relative;
  return {};
}

// The text of FindNamed(name, dirs); empty if there is none.
std::string ReadNamed(const std::string& name, const std::vector<fs::path>& dirs) {
  const fs::path path = FindNamed(name, dirs);
  if (path.empty()) return "";
  try {
    return ReadTextFile(path, "cannot read");
  } catch (const InputError&) {
    return "";  // the page says the plot is missing
  }
}

}  // namespace

std::string ReportHtmlOptions::Check() const {
  if (mosaic_preview_width_px < 16) return "mosaic_preview_width_px must be >= 16";
  return "";
}

std::string ReportHtml(const Report& report, const ReportHtmlInputs& inputs) {
  std::string html =
      "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>omm report: " +
      Escape(report.project) + "</title>\n<style>" + kStyle + "</style>\n</head>\n<body>\n";
  html += HeaderSection(report);
  html += MeasurementsSection(report);
  html += FeaturesSection(report);
  html += MeasureStageSection(report);
  html += MosaicFigure(report, inputs);
  html += CalibrationSection(report, inputs);
  html += MosaicSection(report);
  return html + "</body>\n</html>\n";
}

ReportHtmlInputs ReadReportHtmlInputs(const Report& report, const std::vector<fs::path>& dirs,
                                      const std::vector<MeasurementSpec>& measurements,
                                      const ReportHtmlOptions& options, const StoredImage* mosaic) {
  if (const std::string problem = options.Check(); !problem.empty()) {
    throw std::invalid_argument("ReportHtmlOptions: " + problem);
  }
  ReportHtmlInputs inputs;
  inputs.measurements = measurements;
  if (report.mosaic && mosaic) {
    inputs.mosaic_png = EncodePreviewPng(*mosaic, options.mosaic_preview_width_px);
  } else if (report.mosaic) {
    const fs::path path = FindNamed(report.mosaic->file, dirs);
    if (path.empty()) {
      inputs.mosaic_missing_why = "'" + report.mosaic->file + "' not found";
    } else {
      try {
        inputs.mosaic_png =
            EncodePreviewPng(ReadStoredImage(path), options.mosaic_preview_width_px);
      } catch (const InputError& e) {
        inputs.mosaic_missing_why = e.what();
      }
    }
  }
  if (report.calibration) {
    const ReportObject& extra = report.calibration->extra;
    if (const std::string* name = AsString(Member(extra, "residuals_plot")))
      inputs.residuals_svg = ReadNamed(*name, dirs);
    if (const std::string* name = AsString(Member(extra, "uncertainty_plot")))
      inputs.uncertainty_svg = ReadNamed(*name, dirs);
    if (const ReportObject* study = AsObject(Member(extra, "study"))) {
      if (const std::string* name = AsString(Member(*study, "plot")))
        inputs.study_svg = ReadNamed(*name, dirs);
    }
  }
  return inputs;
}

void WriteReportHtml(const fs::path& path, const Report& report, const std::vector<fs::path>& dirs,
                     const std::vector<MeasurementSpec>& measurements,
                     const ReportHtmlOptions& options, const StoredImage* mosaic) {
  WriteTextFileAtomically(
      path, ReportHtml(report, ReadReportHtmlInputs(report, dirs, measurements, options, mosaic)));
}

}  // namespace omm
