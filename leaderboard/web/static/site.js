"use strict";
(function () {
  function keyOf(row, col, type) {
    var cell = row.cells[col];
    if (!cell) return null;
    var raw = cell.getAttribute("data-sort");
    if (raw === null) raw = cell.textContent.trim();
    if (type === "num") {
      var v = parseFloat(raw);
      return isNaN(v) ? null : v;
    }
    return raw === "" ? null : raw.toLowerCase();
  }

  function setupSort(table) {
    var tbody = table.tBodies[0];
    var headers = table.tHead.rows[0].cells;
    var rows = Array.prototype.slice.call(tbody.rows);
    rows.forEach(function (row, i) { row.setAttribute("data-index", String(i)); });
    var state = { col: -1, dir: 1 };
    function sortBy(col) {
      var type = headers[col].getAttribute("data-type") || "text";
      if (state.col === col) { state.dir = -state.dir; } else { state.dir = type === "num" ? -1 : 1; }
      state.col = col;
      var idx = function (r) { return Number(r.getAttribute("data-index")); };
      var sorted = rows.slice().sort(function (a, b) {
        var ka = keyOf(a, col, type), kb = keyOf(b, col, type);
        if (ka === null || kb === null) {
          if (ka === kb) return idx(a) - idx(b);
          return ka === null ? 1 : -1;  /* empty cells last in both directions */
        }
        var c = type === "num" ? ka - kb : ka.localeCompare(kb);
        return c !== 0 ? c * state.dir : idx(a) - idx(b);
      });
      sorted.forEach(function (r) { tbody.appendChild(r); });
      for (var i = 0; i < headers.length; i++) {
        if (headers[i].querySelector("button")) {
          headers[i].setAttribute("aria-sort", i === col ? (state.dir > 0 ? "ascending" : "descending") : "none");
        }
      }
    }
    Array.prototype.forEach.call(headers, function (th, col) {
      var button = th.querySelector("button");
      if (button) button.addEventListener("click", function () { sortBy(col); });
    });
  }

  function setupFilters(table) {
    var id = table.id;
    var selects = Array.prototype.slice.call(document.querySelectorAll('select[data-table="' + id + '"]'));
    if (!selects.length) return;
    var rows = Array.prototype.slice.call(table.tBodies[0].rows);
    var count = document.querySelector('[data-count="' + id + '"]');
    var empty = document.querySelector('[data-empty="' + id + '"]');
    function apply() {
      var shown = 0;
      rows.forEach(function (row) {
        var ok = selects.every(function (sel) {
          return !sel.value || row.getAttribute("data-" + sel.getAttribute("data-filter")) === sel.value;
        });
        row.hidden = !ok;
        if (ok) shown += 1;
      });
      if (count) count.textContent = "Showing " + shown + " of " + rows.length + " rows";
      if (empty) empty.hidden = shown !== 0;
      selects.forEach(function (sel) {
        var name = sel.getAttribute("data-filter");
        document.querySelectorAll('[data-section-' + name + ']').forEach(function (section) {
          section.hidden = !!sel.value && section.getAttribute("data-section-" + name) !== sel.value;
        });
      });
    }
    selects.forEach(function (sel) { sel.addEventListener("change", apply); });
    var reset = document.querySelector('button[data-reset="' + id + '"]');
    if (reset) reset.addEventListener("click", function () {
      selects.forEach(function (sel) { sel.value = sel.getAttribute("data-default") || ""; });
      apply();
    });
    apply();
  }

  Array.prototype.forEach.call(document.querySelectorAll("table.sortable"), function (table) {
    setupSort(table);
    setupFilters(table);
  });
})();
(function () {
  /* Table 1's grid panes: a select[data-pane=NAME] shows the [data-pane-NAME] block of its value;
     an empty value hides the pane (the "beside it" pane can be turned off). */
  Array.prototype.forEach.call(document.querySelectorAll("select[data-pane]"), function (sel) {
    var name = sel.getAttribute("data-pane");
    function apply() {
      document.querySelectorAll("[data-pane-" + name + "]").forEach(function (block) {
        block.hidden = block.getAttribute("data-pane-" + name) !== sel.value;
      });
      var slot = document.querySelector('[data-pane-slot="' + name + '"]');
      if (slot) slot.hidden = !sel.value;
    }
    sel.addEventListener("change", apply);
    apply();
  });
})();
