// tsog-stream web player: which chunks a time interval needs, read from the manifest alone.
// The same rule as StreamIndex.chunks_for_interval (docs/spec.md section 8.3), so the page
// works against any origin that serves manifest.json and the chunk files (no /v1 API needed).

const TIME_EPSILON = 1e-9; // tsog_stream.temporal.TIME_EPSILON, in frames (or seconds)
const WINDOW_EPSILON = 1e-9; // tsog_stream.container.stream_index.WINDOW_EPSILON, in windows

/** Chunk selection over one parsed manifest (the container index JSON). */
export class SceneIndex {
    constructor(manifest) {
        this.manifest = manifest;
        this.windows = manifest.nodes.filter((n) => n.level === 0).length;
        const fps = manifest.scene.fps;
        this.slack = TIME_EPSILON * (fps ? 1 / fps : 1) + WINDOW_EPSILON * manifest.window_s;
        this.layerCount = Math.max((manifest.layers ?? []).length, 1);
    }

    /** The window holding t (t = k * window_s is in window k), clipped to the scene. */
    window(t) {
        const m = this.manifest;
        const x = (t - m.scene.start_s) / m.window_s + WINDOW_EPSILON;
        return Math.min(Math.floor(Math.min(Math.max(x, 0), this.windows)), this.windows - 1);
    }

    /** Chunks holding Gaussians visible at some time in [a, b], in file order, of the first
     * `layers` quality layers (default: all; a chunk without `layer` is in layer 0). */
    chunksForInterval(a, b, layers = this.layerCount) {
        const m = this.manifest;
        if (!Number.isFinite(a) || !Number.isFinite(b)) return [];
        if (this.windows === 0 || b < m.scene.start_s - this.slack || a > m.scene.end_s + this.slack) {
            return [];
        }
        const first = this.window(a);
        const last = this.window(b);
        const chosen = new Set();
        for (const node of m.nodes) {
            const span = 2 ** Math.min(node.level, 62);
            if (node.index * span > last || (node.index + 1) * span <= first) continue;
            for (const id of node.chunks) {
                const c = m.chunks[id];
                if ((c.layer ?? 0) < layers && c.start_s <= b + this.slack && c.end_s >= a - this.slack) chosen.add(id);
            }
        }
        return [...chosen].map((id) => m.chunks[id]).sort((x, y) => x.offset - y.offset);
    }

    /** Chunks needed to show time t with the first `layers` layers (default: all). */
    chunksFor(t, layers = this.layerCount) {
        return this.chunksForInterval(t, t, layers);
    }
}
