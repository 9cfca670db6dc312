//! What a person looks at rather than reads, drawn from the libraries' results:
//!
//! - [`plots`]: the paper's error histogram (Fig. 6), weighted histograms and estimate curves,
//!   parameter maps, pose overlays, 3-D views and a dataset frame's contact sheet (PNG);
//! - [`search_report`]: a search run's offline HTML page and its figures;
//! - [`improve_page`]: `boxpose improve`'s rounds as a CSV table and an HTML page.
//!
//! Quiet like every boxpose library: nothing is printed; each writer returns what it wrote and
//! publishes its files atomically.

pub mod html;
pub mod improve_page;
pub mod plots;
pub mod search_report;
