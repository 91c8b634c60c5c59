package m6p.yamcs;

import org.yamcs.TmPacket;
import org.yamcs.YConfiguration;
import org.yamcs.tctm.csp.CspPacket;
import org.yamcs.tctm.csp.CspPacketPreprocessor;
import org.yamcs.utils.TimeEncoding;

/**
 * YAMCS's CSP preprocessor (length, cspId filter, CRC32C) with the generation time taken from the
 * packet itself where the M6P ICD gives it one (docs/operations.md, "Simulated time"):
 * <ul>
 * <li>FC TWINSIM reply (port 10, command 12): {@code start_unix_s + sim_time_ns}, the twin's true
 * simulated UTC, to the millisecond;</li>
 * <li>FC telemetry TMGEN..TMALL (commands 1-6: replies from port 10, and the periodic ones of
 * TMPERSET from the FC's own port): {@code rtc_timestamp}, the FC's RTC, whole seconds;</li>
 * <li>COMM BEACON (command 4: the reply and the periodic beacon): {@code utc_s}, the COMM's clock,
 * whole seconds.</li>
 * </ul>
 * Any other packet gets its reception time: YAMCS's mission time, which {@link UdpCspLink} with
 * {@code updateSimulationTime: true} keeps on the twin's simulated time.
 */
public class M6pCspPacketPreprocessor extends CspPacketPreprocessor {
    static final int FC = 3, COMM1 = 1, COMM2 = 2, TM_PORT = 10;
    /** Reply data sizes of the FC's telemetry commands 1-6 (TMGEN, TMATP, TMACD, TMSENS, TMRAWSENS, TMALL). */
    static final int[] FC_TM_SIZES = { 0, 16, 60, 19, 70, 53, 177 };
    static final int TWINSIM = 12, TWINSIM_SIZE = 27, BEACON = 4, BEACON_SIZE = 171;

    public M6pCspPacketPreprocessor(String instance) {
        this(instance, YConfiguration.emptyConfig());
    }

    public M6pCspPacketPreprocessor(String instance, YConfiguration config) {
        super(instance, config);
    }

    @Override
    protected long getGenerationTime(TmPacket packet) {
        long unixMs = packetTimeMillis(packet.getPacket());
        return unixMs < 0 ? packet.getReceptionTime() : TimeEncoding.fromUnixMillisec(unixMs);
    }

    /** The packet's own UTC time in unix milliseconds, or -1 when it has none. */
    static long packetTimeMillis(byte[] b) {
        if (b.length < 6) {
            return -1;
        }
        var csp = new CspPacket(b);
        int n = b.length - 4 - (csp.getCrcFlag() ? 4 : 0); // cmd | result | data
        int cmd = b[4] & 0xff, result = b[5] & 0xff, src = csp.getSource(), sport = csp.getSourcePort();
        if (result != 1) {
            return -1;
        }
        // a reply comes from the port served; what a node sends unasked, from its own (ephemeral) port
        boolean tmPort = sport == TM_PORT || sport >= 16;
        if (src == FC && tmPort && cmd >= 1 && cmd <= 6 && n == 2 + FC_TM_SIZES[cmd]) {
            return 1000L * u32le(b, 6);
        }
        if (isTwinsim(b)) {
            long simNs = u64le(b, 6), startS = u64le(b, 22);
            return startS * 1000L + simNs / 1_000_000L;
        }
        if ((src == COMM1 || src == COMM2) && tmPort && cmd == BEACON && n == 2 + BEACON_SIZE) {
            return 1000L * u32le(b, 10);
        }
        return -1;
    }

    /** A TWINSIM success reply: the twin's true simulated time, which no RTC fault moves. */
    static boolean isTwinsim(byte[] b) {
        if (b.length < 6) {
            return false;
        }
        var csp = new CspPacket(b);
        int n = b.length - 4 - (csp.getCrcFlag() ? 4 : 0);
        return csp.getSource() == FC && csp.getSourcePort() == TM_PORT && (b[4] & 0xff) == TWINSIM
                && (b[5] & 0xff) == 1 && n == 2 + TWINSIM_SIZE;
    }

    static long u32le(byte[] b, int i) {
        return (b[i] & 0xffL) | (b[i + 1] & 0xffL) << 8 | (b[i + 2] & 0xffL) << 16 | (b[i + 3] & 0xffL) << 24;
    }

    static long u64le(byte[] b, int i) {
        return u32le(b, i) | u32le(b, i + 4) << 32;
    }
}
