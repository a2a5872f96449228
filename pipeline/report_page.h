// The HTML page of a report, one look for every command that writes one (fit, reconstruct,
// calibrate, run): a title with the date and the inputs, sections with lists, tables and figures
// (each with a caption saying what its colours mean), the data files linked. Self-contained: one
// file of HTML with its style inline, pictures beside it, no script, no network; a browser opens
// it from the disk.
#ifndef FLAMERIG_PIPELINE_REPORT_PAGE_H_
#define FLAMERIG_PIPELINE_REPORT_PAGE_H_

#include <sstream>
#include <string>
#include <vector>

namespace flamerig {

// `text` with <, >, & and " escaped.
std::string HtmlEscape(const std::string& text);

class ReportPage {
 public:
  // The heading; `inputs` are shown under it as "name: value" pairs in <code>.
  explicit ReportPage(const std::string& title,
                      const std::vector<std::pair<std::string, std::string>>& inputs = {});

  void Section(const std::string& heading);
  // A paragraph of HTML the caller made (escape text with HtmlEscape).
  void Html(const std::string& html);
  void Text(const std::string& text);  // a paragraph of plain text
  void List(const std::vector<std::string>& html_items);
  // A table of plain-text cells, numbers right-aligned.
  void Table(const std::vector<std::string>& header,
             const std::vector<std::vector<std::string>>& rows);
  // A picture beside the page (a path relative to it, percent-encoded where a URL needs it) with
  // its caption.
  void Figure(const std::string& src, const std::string& caption);
  // Something the reader must see: a missing picture, a warning.
  void Warning(const std::string& text);
  // Links to data files beside the page, each with what it holds.
  void Files(const std::vector<std::pair<std::string, std::string>>& files);

  std::string ToHtml() const;
  // Writes the page to `path` atomically (core/atomic_file.h).
  void Write(const std::string& path) const;

 private:
  std::string title_;
  std::ostringstream body_;
};

}  // namespace flamerig

#endif  // FLAMERIG_PIPELINE_REPORT_PAGE_H_
