// The participant's page of `cirl-study serve`: consent, instructions, practice, tasks, end.
// It talks to the server by the JSON API of cirl_study/serve/app.py, every path relative to
// the page (so it runs below a reverse proxy's prefix). The server decides everything: the
// page shows the state it is given, and keeps only the session's token (localStorage).
"use strict";

(() => {
  const app = document.getElementById("app");
  const progress = document.getElementById("progress");
  const storageKey = "cirl-study-token:" + location.pathname;
  let setup = null;
  let token = null;
  let attempt = null; // the task on the page: {name, path, seconds, began, submitting}

  const remember = (value) => {
    token = value;
    try { localStorage.setItem(storageKey, value); } catch (_) { /* private mode: no resume */ }
  };
  const recalled = () => {
    try { return localStorage.getItem(storageKey); } catch (_) { return null; }
  };

  class Refusal extends Error {
    constructor(status, message) { super(message); this.status = status; }
  }

  async function call(method, path, body) {
    const headers = { Accept: "application/json" };
    if (body !== undefined) headers["Content-Type"] = "application/json";
    if (token) headers.Authorization = "Bearer " + token;
    let response;
    try {
      response = await fetch(path, {
        method, headers, cache: "no-store",
        body: body === undefined ? undefined : JSON.stringify(body),
      });
    } catch (_) {
      throw new Refusal(0, "The server could not be reached. Check your connection and try again.");
    }
    let data = null;
    try { data = await response.json(); } catch (_) { data = null; }
    if (!response.ok) {
      throw new Refusal(response.status, (data && data.error) || "The server refused (" + response.status + ").");
    }
    return data;
  }

  const element = (tag, properties = {}, children = []) => {
    const node = document.createElement(tag);
    for (const [key, value] of Object.entries(properties)) {
      if (key === "text") node.textContent = value;
      else if (key === "class") node.className = value;
      else if (key === "on") for (const [event, f] of Object.entries(value)) node.addEventListener(event, f);
      else node.setAttribute(key, value);
    }
    for (const child of children) node.append(child);
    return node;
  };

  const paragraphs = (text) =>
    text.split(/\n\s*\n/).map((part) => element("p", { text: part.replace(/\s*\n\s*/g, " ").trim() }));

  function failure(error) {
    const message = error.status === 401
      ? "This session has continued in another window. Reload the page to continue here."
      : error.message;
    const box = document.getElementById("message");
    if (box) {
      box.textContent = message;
      box.className = "message error";
    } else {
      app.replaceChildren(element("p", { class: "message error", text: message }));
    }
  }

  function page(heading, text, label, path) {
    const button = element("button", { class: "primary", id: "continue", text: label });
    button.addEventListener("click", async () => {
      button.disabled = true;
      try { show(await call("POST", path)); } catch (error) { button.disabled = false; failure(error); }
    });
    app.replaceChildren(element("section", { class: "page" }, [
      element("h2", { text: heading }), ...paragraphs(text),
      element("div", { class: "actions" }, [button]),
      element("p", { class: "message", id: "message", role: "status" }),
    ]));
    button.focus();
  }

  function show(state) {
    document.removeEventListener("keydown", onKey);
    progress.textContent = state.stage === "done" ? "" : `${state.done} of ${state.count} tasks done`;
    if (state.stage === "consent") return page("Consent", state.text, "I agree", "api/consent");
    if (state.stage === "instructions") return page("Instructions", state.text, "Continue", "api/instructions");
    if (state.stage === "practice" || state.stage === "task") return showTask(state.task);
    return finish(state);
  }

  function finish(state) {
    attempt = null;
    const parts = [element("h2", { text: "Thank you!" })];
    if (state.completion_url) {
      parts.push(element("p", { text: "You have finished. Taking you back to the study's site…" }));
      parts.push(element("p", {}, [element("a", { href: state.completion_url, id: "completion", text: "Continue" })]));
      setTimeout(() => location.assign(state.completion_url), 1500);
    } else {
      parts.push(element("p", { text: "You have finished. Your completion code:" }));
      parts.push(element("p", {}, [element("span", { class: "code", id: "completion", text: state.completion_code })]));
    }
    app.replaceChildren(element("section", { class: "page" }, parts));
  }

  // ---- a task ---------------------------------------------------------------------------

  const board = () => setup.board;
  const key = (x, y) => x + "," + y;
  const last = () => attempt.path[attempt.path.length - 1];
  const moves = () => attempt.path.length - 1;
  const goalAt = (x, y) => setup.board.tiles[board().rows[board().height - 1 - y][x]].goal;
  const hasGoals = () => Object.values(board().tiles).some((tile) => tile.goal);
  const finished = () => {
    const [x, y] = last();
    return hasGoals() ? goalAt(x, y) : moves() === board().max_moves;
  };

  function showTask(task) {
    if (!attempt || attempt.name !== task.name || attempt.practice !== task.practice) {
      attempt = { name: task.name, practice: task.practice, began: performance.now() };
      restart();
    }
    attempt.submitting = false;
    const b = board();
    document.documentElement.style.setProperty("--columns", String(b.width));
    const grid = element("div", { class: "grid", id: "grid", role: "grid", "aria-label": "the grid of tiles" });
    grid.style.gridTemplateColumns = `repeat(${b.width}, var(--cell))`;
    for (let row = 0; row < b.height; row++) {
      const y = b.height - 1 - row;
      for (let x = 0; x < b.width; x++) {
        const tile = b.tiles[b.rows[row][x]];
        const what = tile.goal ? "goal" : tile.feature ? tile.feature + " tile" : "plain tile";
        const cell = element("button", {
          class: "cell" + (tile.goal ? " goal" : "") + (x === b.start[0] && y === b.start[1] ? " start" : ""),
          "data-x": String(x), "data-y": String(y), "aria-label": `${what}, column ${x + 1}, row ${row + 1}`,
        }, [element("span", { class: "letter", text: tile.letter })]);
        cell.style.background = tile.colour;
        cell.style.color = tile.text_colour;
        cell.addEventListener("click", () => step(x, y));
        grid.append(cell);
      }
    }
    swipes(grid);
    const items = task.legend.map((meaning) => {
      const swatch = element("span", { class: "swatch", text: meaning.letters });
      swatch.style.background = meaning.colour;
      const worth = meaning.kind === "safe" ? "safe" : meaning.kind === "dangerous"
        ? `dangerous (${points(meaning.weight)})` : `good (${points(meaning.weight)})`;
      return element("li", {}, [swatch, element("span", { class: meaning.kind, text: `${meaning.feature}: ${worth}` })]);
    });
    for (const tile of Object.values(b.tiles).filter((t) => t.goal)) {
      const swatch = element("span", { class: "swatch goal", text: tile.letter });
      swatch.style.background = tile.colour;
      swatch.style.color = tile.text_colour;
      items.push(element("li", {}, [swatch, element("span", { text: "goal: the task ends on entering it" })]));
    }
    if (task.move_weight !== null && task.move_weight !== 0) {
      items.push(element("li", {}, [element("span", { class: "swatch", text: "→" }),
        element("span", { text: `each move: ${points(task.move_weight)}` })]));
    }
    const heading = task.practice ? "Practice (not recorded)" : `Task ${task.number} of ${task.count}`;
    const restartButton = element("button", { id: "restart", text: "Restart this task" });
    restartButton.addEventListener("click", () => { restart(); draw(); });
    const submitButton = element("button", { class: "primary", id: "submit", text: "Submit" });
    submitButton.addEventListener("click", submit);
    app.replaceChildren(element("section", { class: "task" }, [
      grid,
      element("div", { class: "side" }, [
        element("h2", { text: heading }),
        element("ul", { class: "legend" }, items),
        element("p", { class: "counter" }, [
          "Moves: ", element("b", { id: "moves" }), " · left: ", element("b", { id: "left" }),
        ]),
        element("div", { class: "actions" }, [restartButton, submitButton]),
        element("p", { class: "message", id: "message", role: "status" }),
        element("p", { class: "hint", text: "Arrow keys, a click or tap on a neighbouring tile, or a swipe move the figure." }),
      ]),
    ]));
    document.addEventListener("keydown", onKey);
    draw();
  }

  const points = (weight) => {
    const shown = Math.abs(weight) === 1 ? "1 point" : `${Math.abs(weight)} points`;
    return (weight < 0 ? "−" : "+") + shown;
  };

  function restart() {
    attempt.path = [[board().start[0], board().start[1]]];
    attempt.seconds = [0];
  }

  function step(x, y) {
    if (!attempt || attempt.submitting) return;
    const b = board();
    const [px, py] = last();
    const distance = Math.abs(x - px) + Math.abs(y - py);
    const message = document.getElementById("message");
    if (finished()) return;
    if (x < 0 || y < 0 || x >= b.width || y >= b.height) return;
    if (distance > 1 || (distance === 0 && !b.stay)) {
      message.textContent = "Move to a neighbouring tile (up, down, left or right).";
      message.className = "message";
      return;
    }
    if (moves() >= b.max_moves) return;
    const elapsed = Math.max(attempt.seconds[attempt.seconds.length - 1],
      Math.round(performance.now() - attempt.began) / 1000);
    attempt.path.push([x, y]);
    attempt.seconds.push(elapsed);
    draw();
  }

  function onKey(event) {
    const moved = { ArrowUp: [0, 1], ArrowDown: [0, -1], ArrowLeft: [-1, 0], ArrowRight: [1, 0] }[event.key];
    if (!moved || !attempt) return;
    event.preventDefault();
    const [x, y] = last();
    step(x + moved[0], y + moved[1]);
  }

  function swipes(grid) {
    let from = null;
    grid.addEventListener("touchstart", (event) => {
      const touch = event.changedTouches[0];
      from = [touch.clientX, touch.clientY];
    }, { passive: true });
    grid.addEventListener("touchend", (event) => {
      if (!from) return;
      const touch = event.changedTouches[0];
      const dx = touch.clientX - from[0];
      const dy = touch.clientY - from[1];
      from = null;
      if (Math.max(Math.abs(dx), Math.abs(dy)) < 30) return; // a tap: the click moves
      event.preventDefault();
      const [x, y] = last();
      if (Math.abs(dx) > Math.abs(dy)) step(x + Math.sign(dx), y);
      else step(x, y - Math.sign(dy));
    });
  }

  function draw() {
    const b = board();
    const visited = new Set(attempt.path.map(([x, y]) => key(x, y)));
    const [ax, ay] = last();
    for (const cell of document.querySelectorAll(".cell")) {
      const x = Number(cell.dataset.x);
      const y = Number(cell.dataset.y);
      cell.classList.toggle("visited", visited.has(key(x, y)) && !(x === ax && y === ay));
      const agent = cell.querySelector(".agent");
      if (x === ax && y === ay && !agent) cell.append(element("span", { class: "agent", "aria-label": "you are here" }));
      if (!(x === ax && y === ay) && agent) agent.remove();
    }
    document.getElementById("moves").textContent = String(moves());
    document.getElementById("left").textContent = String(b.max_moves - moves());
    const done = finished();
    document.getElementById("submit").disabled = !done || attempt.submitting;
    document.getElementById("restart").disabled = attempt.submitting;
    const message = document.getElementById("message");
    message.className = "message";
    if (done) message.textContent = "Done: submit, or restart the task.";
    else if (moves() >= b.max_moves) message.textContent = "No moves left: restart the task.";
    else message.textContent = "";
  }

  async function submit() {
    if (!attempt || attempt.submitting || !finished()) return;
    attempt.submitting = true;
    draw();
    document.getElementById("message").textContent = "Saving…";
    const path = attempt.practice ? "api/practice" : "api/demonstration";
    try {
      const state = await call("POST", path, { task: attempt.name, path: attempt.path, seconds: attempt.seconds });
      attempt = null;
      show(state);
    } catch (error) {
      attempt.submitting = false;
      draw();
      failure(error);
    }
  }

  async function begin() {
    try {
      setup = await call("GET", "api/setup");
      document.title = setup.title;
      document.getElementById("title").textContent = setup.title;
      const parameter = setup.participant_parameter;
      const participant = parameter ? new URLSearchParams(location.search).get(parameter) : null;
      token = recalled();
      const state = await call("POST", "api/start", { participant: participant || null, token: token || null });
      if (state.token) remember(state.token);
      show(state);
    } catch (error) {
      failure(error);
    }
  }

  begin();
})();
