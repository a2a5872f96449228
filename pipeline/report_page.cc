#include "pipeline/report_page.h"

#include <cctype>
#include <ctime>

#include "core/atomic_file.h"

namespace flamerig {

namespace {

// A cell that reads as a number ("-12.5", "3e+14", "98%", "1.2 s") is right-aligned.
bool Numeric(const std::string& cell) {
  if (cell.empty()) return false;
  const char c = cell[0];
  return std::isdigit(static_cast<unsigned char>(c)) ||
         ((c == '-' || c == '+' || c == '.') && cell.size() > 1 &&
          std::isdigit(static_cast<unsigned char>(cell[1])));
}

constexpr const char* kStyle =
    "body{font-family:'DejaVu Sans',Arial,sans-serif;margin:0 auto;padding:1.5em 2em;"
    "max-width:1200px;color:#222;line-height:1.4}"
    "h1{font-size:1.6em;margin:0 0 .2em}h2{font-size:1.25em;margin-top:1.6em;"
    "border-bottom:1px solid #ddd;padding-bottom:.2em}"
    ".inputs{color:#555;font-size:.9em}.inputs code{background:#f2f2f2;padding:0 3px}"
    "table{border-collapse:collapse;font-size:.85em;margin:.5em 0}"
    "td,th{border:1px solid #ccc;padding:2px 8px}th{background:#f2f2f2;text-align:left}"
    "td.n{text-align:right;font-variant-numeric:tabular-nums}"
    "figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}"
    "figcaption{font-size:.9em;color:#444;margin-top:.3em}"
    ".warning{background:#fff3cd;border-left:4px solid #e0a800;padding:.4em .8em}"
    "code{background:#f2f2f2}";

// A relative path as a URL: the characters a URL gives a meaning to (%, #, ?, space, quotes, <,
// >) percent-encoded, so that a camera named "cam#1" still finds coverage_cam#1.png.
std::string UrlPath(const std::string& path) {
  static const char* kHex = "0123456789ABCDEF";
  std::string out;
  for (unsigned char c : path) {
    if (c == '%' || c == '#' || c == '?' || c == ' ' || c == '"' || c == '\'' || c == '<' ||
        c == '>' || c < 0x20) {
      out += '%';
      out += kHex[c >> 4];
      out += kHex[c & 15];
    } else {
      out += static_cast<char>(c);
    }
  }
  return out;
}

}  // namespace

std::string HtmlEscape(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '&':
        out += "&amp;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

ReportPage::ReportPage(const std::string& title,
                       const std::vector<std::pair<std::string, std::string>>& inputs)
    : title_(title) {
  const std::time_t now = std::time(nullptr);
  char date[64];
  std::strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
  body_ << "<h1>" << HtmlEscape(title) << "</h1>\n<p class=\"inputs\">" << date;
  for (const auto& [name, value] : inputs)
    body_ << " &middot; " << HtmlEscape(name) << ": <code>" << HtmlEscape(value) << "</code>";
  body_ << "</p>\n";
}

void ReportPage::Section(const std::string& heading) {
  body_ << "<h2>" << HtmlEscape(heading) << "</h2>\n";
}

void ReportPage::Html(const std::string& html) { body_ << "<p>" << html << "</p>\n"; }

void ReportPage::Text(const std::string& text) { Html(HtmlEscape(text)); }

void ReportPage::List(const std::vector<std::string>& html_items) {
  body_ << "<ul>\n";
  for (const auto& item : html_items) body_ << "<li>" << item << "</li>\n";
  body_ << "</ul>\n";
}

void ReportPage::Table(const std::vector<std::string>& header,
                       const std::vector<std::vector<std::string>>& rows) {
  body_ << "<table>\n<tr>";
  for (const auto& h : header) body_ << "<th>" << HtmlEscape(h) << "</th>";
  body_ << "</tr>\n";
  for (const auto& row : rows) {
    body_ << "<tr>";
    for (const auto& cell : row)
      body_ << (Numeric(cell) ? "<td class=\"n\">" : "<td>") << HtmlEscape(cell) << "</td>";
    body_ << "</tr>\n";
  }
  body_ << "</table>\n";
}

void ReportPage::Figure(const std::string& src, const std::string& caption) {
  body_ << "<figure><img src=\"" << HtmlEscape(UrlPath(src)) << "\" alt=\"" << HtmlEscape(caption)
        << "\"><figcaption>" << HtmlEscape(caption) << "</figcaption></figure>\n";
}

void ReportPage::Warning(const std::string& text) {
  body_ << "<p class=\"warning\">" << HtmlEscape(text) << "</p>\n";
}

void ReportPage::Files(const std::vector<std::pair<std::string, std::string>>& files) {
  body_ << "<ul>\n";
  for (const auto& [path, what] : files)
    body_ << "<li><a href=\"" << HtmlEscape(UrlPath(path)) << "\"><code>" << HtmlEscape(path)
          << "</code></a>: " << HtmlEscape(what) << "</li>\n";
  body_ << "</ul>\n";
}

std::string ReportPage::ToHtml() const {
  return "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>" +
         HtmlEscape(title_) + "</title>\n<style>" + kStyle + "</style></head>\n<body>\n" +
         body_.str() + "</body></html>\n";
}

void ReportPage::Write(const std::string& path) const { WriteFileAtomically(path, ToHtml()); }

}  // namespace flamerig
