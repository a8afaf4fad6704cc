// tsog-stream web player: how many quality layers to keep fetching, from throughput and
// deadlines. A line-for-line mirror of tsog_stream/client/adaptive.py (same constants, same
// rules; tests/test_player_adapt.py runs both on the same cases and compares every choice).

export const EWMA_WEIGHT = 0.3;
export const SAFETY = 0.85;
export const STARTUP_FACTOR = 4.0;
export const STARTUP_MIN_S = 2.0;
export const UPGRADE_MARGIN = 0.8;
export const BASE_LATE_S = 0.5;
export const HORIZON_S = 4.0;
export const REPLAN_S = 0.5;

/** Bytes per second the link gives: an EWMA over busy time (time with a request in flight). */
export class Throughput {
    constructor(clock = () => performance.now() / 1000) {
        this.clock = clock;
        this.inFlight = 0;
        this.busySince = 0;
        this.busy = 0;
        this.bytes = 0;
        this.estimate = null;
    }

    /** A request went out. */
    started() {
        if (this.inFlight === 0) this.busySince = this.clock();
        this.inFlight += 1;
    }

    /** A request that went out came back with `nbytes` (0 for a failure). */
    finished(nbytes) {
        const now = this.clock();
        this.busy += now - this.busySince;
        this.busySince = now;
        this.inFlight = Math.max(this.inFlight - 1, 0);
        this.bytes += nbytes;
        if (this.bytes > 0 && this.busy > 0) {
            const sample = this.bytes / this.busy;
            this.estimate = this.estimate === null ? sample : this.estimate + EWMA_WEIGHT * (sample - this.estimate);
            this.bytes = 0;
            this.busy = 0;
        }
    }
}

/** Chunks by the scene time they are first needed from t on, base layers first. */
export function dueOrder(chunks, t) {
    const key = (c) => [Math.max(c.start_s, t), c.layer ?? 0, c.offset];
    return [...chunks].sort((a, b) => {
        const [x, y] = [key(a), key(b)];
        return x[0] - y[0] || x[1] - y[1] || x[2] - y[2];
    });
}

/** Wall seconds playback must wait so that `chunks`, fetched back to back in due order at
 * `rate` bytes/s, each arrive by the time scene time t has advanced to their first second. */
export function delayNeeded(chunks, t, speed, rate) {
    if (chunks.length === 0) return -Infinity;
    if (rate <= 0) return Infinity;
    let worst = -Infinity;
    let sent = 0;
    for (const c of dueOrder(chunks, t)) {
        sent += c.length;
        worst = Math.max(worst, sent / rate - Math.max(c.start_s - t, 0) / speed);
    }
    return worst;
}

/** How many layers to keep fetching for [t, end] (1 at least); see chooseLayers in
 * adaptive.py for the rules (startup when current is 0, then keep, raise or drop). */
export function chooseLayers(index, t, end, { speed, rate, have, current, allowance }) {
    const budget = (rate ?? 0) * SAFETY;
    const missing = (layers) => index.chunksForInterval(t, end, layers).filter((c) => !have(c.id));
    if (current === 0) {
        let best = 1;
        for (let layers = 1; layers <= index.layerCount; layers++) {
            if (delayNeeded(missing(layers), t, speed, budget) <= allowance) best = layers;
        }
        return best;
    }
    if (delayNeeded(missing(1), t, speed, budget) > BASE_LATE_S) return 1;
    const remaining = Math.max(end - t, 0) / speed;
    const fits = (layers, share) => budget > 0
        && missing(layers).reduce((n, c) => n + c.length, 0) / budget <= share * remaining;
    let level = current;
    while (level > 1 && !fits(level, 1.0)) level -= 1;
    if (level === current && level < index.layerCount && fits(level + 1, UPGRADE_MARGIN)) level += 1;
    return level;
}

/** How much longer than the first picture a playback may wait for more layers. */
export function startupAllowance(firstPictureS) {
    return Math.max(STARTUP_MIN_S, STARTUP_FACTOR * firstPictureS);
}

/** The most layers whose every chunk for t has arrived (0: not even the base). */
export function layersShown(index, t, have) {
    const chunks = index.chunksFor(t); // every layer's, chosen once (a frame asks this each time)
    let shown = 0;
    for (let layer = 0; layer < index.layerCount; layer++) {
        if (!chunks.every((c) => (c.layer ?? 0) !== layer || have(c.id))) break;
        shown = layer + 1;
    }
    return shown;
}
