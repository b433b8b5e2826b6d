// MathJax for pymdownx.arithmatex (generic mode), as in mkdocs-material's "Math" setup:
// typesets \( ... \) and \[ ... \] inside the elements arithmatex marks, again after each
// instant-navigation page change.
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"]],
    displayMath: [["\\[", "\\]"]],
    processEscapes: true,
    processEnvironments: true
  },
  options: {
    ignoreHtmlClass: ".*|",
    processHtmlClass: "arithmatex"
  }
};

document$.subscribe(() => {
  // MathJax comes from a CDN: offline it never loads and the TeX stays as written
  if (!window.MathJax || !window.MathJax.startup) return;
  MathJax.startup.output.clearCache();
  MathJax.typesetClear();
  MathJax.texReset();
  MathJax.typesetPromise();
});
