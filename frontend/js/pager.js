// Paging of the list pages: the API answers at most PAGE_SIZE rows a request with the total
// `count`; the page says which rows it shows and steps through the rest (offset in the URL).

import { h } from "./dom.js";

export const PAGE_SIZE = 100;

/** The offset in the page URL (?offset=), a whole multiple of PAGE_SIZE, never negative. */
export function offsetFromUrl() {
  const n = Number(new URLSearchParams(location.search).get("offset"));
  return Number.isInteger(n) && n > 0 ? n - (n % PAGE_SIZE) : 0;
}

/** "101–200 of 345" with Previous / Next buttons calling onPage(newOffset); empty if it all fits. */
export function pager({ id, offset, shown, count, onPage }) {
  const nav = h("nav", { class: "pager", id, "aria-label": "pages" });
  if (offset === 0 && count <= shown) return nav;
  const last = offset + shown;
  nav.appendChild(h("button", { type: "button", class: "small prev", disabled: offset === 0,
    onclick: () => onPage(Math.max(0, offset - PAGE_SIZE)) }, "← Previous"));
  nav.appendChild(h("span", { class: "muted range" },
    shown ? `${offset + 1}–${last} of ${count}` : `none past ${offset} of ${count}`));
  nav.appendChild(h("button", { type: "button", class: "small next", disabled: last >= count,
    onclick: () => onPage(offset + PAGE_SIZE) }, "Next →"));
  return nav;
}
