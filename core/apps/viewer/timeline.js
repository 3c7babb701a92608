// The state of a recorded run at a moment, rebuilt from its change records. No DOM here: the
// page uses it, and the tests run it under Node against the Python reference
// (amslam/viewer/timeline.py), so both must agree record for record.
"use strict";

(function (root) {
  const INVALID = "INVALID";
  const SNAPSHOT_EVERY = 64; // full states kept every so many records: a seek replays at most this many

  /** Index of the first element of the ascending array `values` greater than `x`. */
  function upperBound(values, x) {
    let lo = 0;
    let hi = values.length;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (values[mid] <= x) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }

  function copyState(s) {
    return { tick: s.tick, index: s.index, nodes: Object.assign({}, s.nodes), bb: Object.assign({}, s.bb) };
  }

  function apply(state, record) {
    state.tick = record[1];
    const nodes = record[2] || {};
    for (const id in nodes) state.nodes[id] = nodes[id];
    const bb = record[3] || {};
    for (const key in bb) state.bb[key] = bb[key];
  }

  /** Tree change records [t, tick, {id: [status, feedback]}, {key: value}] and the states they build. */
  class TreeTimeline {
    constructor(structure, records) {
      this.structure = structure || [];
      this.records = [];
      this.times = [];
      this.snapshots = [{ tick: 0, index: 0, nodes: {}, bb: {} }];
      this.add(records || []);
    }

    /** Append records (ascending time, after the ones held). */
    add(records) {
      for (const r of records) {
        this.records.push(r);
        this.times.push(r[0]);
      }
      // extend the snapshots: snapshot k is the state after the first k * SNAPSHOT_EVERY records
      let last = this.snapshots[this.snapshots.length - 1];
      while ((this.snapshots.length) * SNAPSHOT_EVERY <= this.records.length) {
        const s = copyState(last);
        const end = this.snapshots.length * SNAPSHOT_EVERY;
        for (let i = s.index; i < end; i++) apply(s, this.records[i]);
        s.index = end;
        this.snapshots.push(s);
        last = s;
      }
    }

    /** {tick, index, nodes, bb}: `index` records (those with time <= t) applied. */
    stateAt(t) {
      const n = upperBound(this.times, t);
      const k = Math.min(Math.floor(n / SNAPSHOT_EVERY), this.snapshots.length - 1);
      const s = copyState(this.snapshots[k]);
      for (let i = s.index; i < n; i++) apply(s, this.records[i]);
      s.index = n;
      return s;
    }

    status(state, id) {
      const v = state.nodes[id];
      return v ? v[0] : INVALID;
    }

    /** Time of the first record after t, or of the last record before t (for stepping). */
    nextChange(t) {
      const i = upperBound(this.times, t);
      return i < this.times.length ? this.times[i] : null;
    }

    previousChange(t) {
      // the latest record strictly before t
      let i = upperBound(this.times, t) - 1;
      while (i >= 0 && this.times[i] >= t) i--;
      return i >= 0 ? this.times[i] : null;
    }
  }

  /** [x, y, z, yaw] at t from samples [t, x, y, z, yaw]; null before the first sample. */
  function poseAt(trajectory, t, times) {
    if (!trajectory || trajectory.length === 0 || t < trajectory[0][0]) return null;
    const ts = times || trajectory.map((p) => p[0]);
    const i = upperBound(ts, t) - 1;
    if (i >= trajectory.length - 1) return trajectory[trajectory.length - 1].slice(1, 5);
    const a = trajectory[i];
    const b = trajectory[i + 1];
    const span = b[0] - a[0];
    const s = span > 0 ? (t - a[0]) / span : 0;
    const dyaw = Math.atan2(Math.sin(b[4] - a[4]), Math.cos(b[4] - a[4]));
    const yaw = Math.atan2(Math.sin(a[4] + s * dyaw), Math.cos(a[4] + s * dyaw));
    return [a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]), a[3] + s * (b[3] - a[3]), yaw];
  }

  /** The tour [[kind, x, y, z], ...] of the latest `replan` event at or before t. */
  function tourAt(events, t) {
    let tour = [];
    for (const e of events) {
      if (e.t > t) break;
      if (e.event === "replan") tour = e.tour || [];
    }
    return tour;
  }

  /** Every distinct SLC viewpoint the tours held up to t, as [x, y, z]. */
  function slcViewpointsUntil(events, t) {
    const seen = new Map();
    for (const e of events) {
      if (e.t > t) break;
      if (e.event !== "replan") continue;
      for (const item of e.tour || []) {
        if (item[0] === "slc") {
          const key = item.slice(1).join(",");
          if (!seen.has(key)) seen.set(key, item.slice(1));
        }
      }
    }
    return Array.from(seen.values());
  }

  const api = { INVALID, SNAPSHOT_EVERY, upperBound, TreeTimeline, poseAt, tourAt, slcViewpointsUntil };
  if (typeof module !== "undefined" && module.exports) module.exports = api;
  else root.AmslamTimeline = api;
})(typeof window !== "undefined" ? window : globalThis);
