// Renders the pages' math (pymdownx.arithmatex, generic mode) with the KaTeX files vendored
// beside this script: nothing is fetched from the network.  Material's instant navigation
// swaps pages without a reload, so the math is rendered on each page it shows.
function renderPageMath() {
  renderMathInElement(document.body, {
    delimiters: [
      { left: "$$", right: "$$", display: true },
      { left: "\\(", right: "\\)", display: false },
      { left: "\\[", right: "\\]", display: true },
    ],
    throwOnError: false,
  });
}
if (typeof document$ !== "undefined") {
  document$.subscribe(renderPageMath);
} else {
  document.addEventListener("DOMContentLoaded", renderPageMath);
}
