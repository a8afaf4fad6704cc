// tsog-stream web player: how fast the page makes chunks ready (fetched, checked, decoded,
// handed to the engine). On a fast link the page's own decoding is the limit, so this rate,
// not the link's, chooses how many quality layers playback can keep up with.
import { EWMA_WEIGHT, Throughput } from './adapt.js';

/** Busy seconds a rate sample spans at least: loads finish in bursts (several at the end of
 * one long main-thread task), and a sample per load would see some take no time at all. */
export const SAMPLE_S = 0.25;

/** Bytes per second the page makes ready: Throughput's EWMA over busy time (time with a load
 * in flight), each sample spanning at least SAMPLE_S of it. */
export class ReadyRate extends Throughput {
    /** A load that started came to an end with `nbytes` ready (0 for a failure or a drop):
     * while others are in flight and the sample spans under SAMPLE_S, only added up. */
    finished(nbytes) {
        const now = this.clock();
        const busy = this.busy + now - this.busySince;
        if (busy >= SAMPLE_S || this.inFlight <= 1) {
            super.finished(nbytes);
            return;
        }
        [this.busy, this.busySince, this.inFlight] = [busy, now, this.inFlight - 1];
        this.bytes += nbytes;
    }
}
