package m6p.yamcs;

import java.io.IOException;
import java.net.DatagramPacket;
import java.net.DatagramSocket;
import java.net.InetSocketAddress;
import java.nio.ByteBuffer;
import java.util.Arrays;
import java.util.concurrent.Executors;
import java.util.concurrent.ScheduledExecutorService;
import java.util.concurrent.TimeUnit;

import org.yamcs.ConfigurationException;
import org.yamcs.Spec;
import org.yamcs.Spec.OptionType;
import org.yamcs.TmPacket;
import org.yamcs.YConfiguration;
import org.yamcs.commanding.PreparedCommand;
import org.yamcs.tctm.AbstractTcTmParamLink;
import org.yamcs.tctm.TmSink;
import org.yamcs.tctm.csp.CspPacket;
import org.yamcs.time.SimulationTimeService;
import org.yamcs.utils.TimeEncoding;

/**
 * CSP over UDP, one packet per datagram, telemetry and commands on <b>one socket bound to one
 * address</b> (127.0.0.1 by default). YAMCS's own UDP links bind the wildcard address
 * (UdpTmDataLink has no host key; UdpTcDataLink sends from a wildcard ephemeral socket); this
 * one listens on {@code address:port} only and sends commands from it to {@code peerHost:peerPort},
 * the twin's {@code m6p-twin run --udp PEER,ADDRESS}.
 * <p>
 * With {@code twinsimPeriod > 0} it also asks the twin's FC for TWINSIM every that many seconds
 * (at start too), from CSP address {@code cspAddress} port {@code cspPort}: with
 * {@code updateSimulationTime: true} and {@link M6pCspPacketPreprocessor}, the replies set YAMCS's
 * mission time to the twin's simulated time before any other telemetry arrives. These requests
 * are the link's own: they are not in the command history.
 * <p>
 * {@code updateSimulationTime: true} (with {@code SimulationTimeService}) moves YAMCS's mission
 * time with the packets' own times, as YAMCS's links do, but by a rule of its own, so that the
 * mission time never steps back by the RTC's truncation: a TWINSIM reply (the twin's true time)
 * always sets it; before the first one, a packet with a time of its own (the FC's RTC, the COMM's
 * clock) sets it when that time is ahead of it. Between packets it runs at 1 s per second.
 */
public class UdpCspLink extends AbstractTcTmParamLink implements Runnable {
    private String address, peerHost;
    private int port, peerPort, maxLength, twinsimPeriod, cspAddress, cspPort;
    private InetSocketAddress peer;
    private volatile DatagramSocket socket;
    private ScheduledExecutorService timer;
    private TmSink sink;
    private volatile boolean sawTwinsim;

    @Override
    public Spec getSpec() {
        var spec = getDefaultSpec();
        spec.addOption("address", OptionType.STRING).withDefault("127.0.0.1");
        spec.addOption("port", OptionType.INTEGER).withRequired(true);
        spec.addOption("peerHost", OptionType.STRING).withDefault("127.0.0.1");
        spec.addOption("peerPort", OptionType.INTEGER).withRequired(true);
        spec.addOption("maxLength", OptionType.INTEGER).withDefault(1500);
        spec.addOption("twinsimPeriod", OptionType.INTEGER).withDefault(0);
        spec.addOption("cspAddress", OptionType.INTEGER).withDefault(17);
        spec.addOption("cspPort", OptionType.INTEGER).withDefault(40);
        return spec;
    }

    @Override
    public void init(String instance, String name, YConfiguration config) throws ConfigurationException {
        super.init(instance, name, config);
        address = config.getString("address", "127.0.0.1");
        port = config.getInt("port");
        peerHost = config.getString("peerHost", "127.0.0.1");
        peerPort = config.getInt("peerPort");
        maxLength = config.getInt("maxLength", 1500);
        twinsimPeriod = config.getInt("twinsimPeriod", 0);
        cspAddress = config.getInt("cspAddress", 17);
        cspPort = config.getInt("cspPort", 40);
        peer = new InetSocketAddress(peerHost, peerPort);
    }

    @Override
    protected void doStart() {
        try {
            socket = new DatagramSocket(new InetSocketAddress(address, port));
        } catch (IOException e) {
            notifyFailed(e);
            return;
        }
        var reader = new Thread(this, "csp-udp-" + linkName);
        reader.setDaemon(true);
        reader.start();
        if (twinsimPeriod > 0) {
            timer = Executors.newSingleThreadScheduledExecutor(r -> {
                var t = new Thread(r, "csp-udp-twinsim-" + linkName);
                t.setDaemon(true);
                return t;
            });
            timer.scheduleAtFixedRate(this::requestTwinsim, 0, twinsimPeriod, TimeUnit.SECONDS);
        }
        notifyStarted();
    }

    @Override
    protected void doStop() {
        if (timer != null) {
            timer.shutdownNow();
        }
        if (socket != null) {
            socket.close();
        }
        notifyStopped();
    }

    @Override
    public void run() {
        var datagram = new DatagramPacket(new byte[maxLength], maxLength);
        // not isRunning(): the thread starts while the service is still STARTING
        while (!socket.isClosed()) {
            try {
                socket.receive(datagram);
            } catch (IOException e) {
                if (!socket.isClosed()) {
                    log.warn("UDP receive on {}:{}: {}", address, port, e.toString());
                    continue;
                }
                return;
            }
            if (isDisabled()) {
                continue;
            }
            byte[] bytes = Arrays.copyOfRange(datagram.getData(), datagram.getOffset(),
                    datagram.getOffset() + datagram.getLength());
            dataIn(1, bytes.length);
            if (updateSimulationTime && M6pCspPacketPreprocessor.isTwinsim(bytes) && !CspPacket.getCrcFlag(bytes)) {
                // the twin's true time: the clock first, so that this packet's reception time is on it
                sawTwinsim = true;
                ((SimulationTimeService) timeService).setSimElapsedTime(
                        TimeEncoding.fromUnixMillisec(M6pCspPacketPreprocessor.packetTimeMillis(bytes)));
            }
            TmPacket tm = packetPreprocessor.process(new TmPacket(timeService.getMissionTime(), bytes));
            if (tm != null) {
                packetCount.incrementAndGet();
                processPacket(tm);
            }
        }
    }

    @Override
    public boolean sendCommand(PreparedCommand pc) {
        if (isDisabled()) {
            failedCommand(pc.getCommandId(), "link " + linkName + " is disabled");
            return true;
        }
        byte[] binary = postprocess(pc);
        if (binary == null) {
            return true;
        }
        try {
            socket.send(new DatagramPacket(binary, binary.length, peer));
        } catch (IOException e) {
            failedCommand(pc.getCommandId(), "UDP send to " + peer + ": " + e);
            return true;
        }
        dataOut(1, binary.length);
        ackCommand(pc.getCommandId());
        return true;
    }

    @Override
    public void setTmSink(TmSink tmSink) {
        super.setTmSink(tmSink);
        this.sink = tmSink;
    }

    /** As AbstractTcTmParamLink's, with the rule of the class comment for the mission time. */
    @Override
    protected void processPacket(TmPacket tm) {
        sink.processPacket(tm);
        if (!updateSimulationTime || tm.isInvalid()) {
            return;
        }
        var sts = (SimulationTimeService) timeService;
        if (M6pCspPacketPreprocessor.isTwinsim(tm.getPacket())) {
            sawTwinsim = true;
            sts.setSimElapsedTime(tm.getGenerationTime());
        } else if (!sawTwinsim && tm.getGenerationTime() > sts.getMissionTime()) {
            sts.setSimElapsedTime(tm.getGenerationTime());
        }
    }

    /** FC (3) port 10 command 12, TWINSIM: the twin's simulated time. */
    private void requestTwinsim() {
        if (isDisabled() || socket.isClosed()) {
            return;
        }
        int header = 2 << 30 | (cspAddress & 0x1f) << 25 | 3 << 20 | 10 << 14 | (cspPort & 0x3f) << 8;
        byte[] b = ByteBuffer.allocate(5).putInt(header).put((byte) 12).array();
        try {
            socket.send(new DatagramPacket(b, b.length, peer));
            dataOut(1, b.length);
        } catch (IOException e) {
            log.debug("TWINSIM request to {}: {}", peer, e.toString());
        }
    }

    @Override
    protected Status connectionStatus() {
        return socket != null && !socket.isClosed() ? Status.OK : Status.UNAVAIL;
    }

    @Override
    public String getDetailedStatus() {
        if (isDisabled()) {
            return "DISABLED";
        }
        return String.format("on %s:%d, sending to %s:%d, %d packets in", address, port, peerHost, peerPort,
                packetCount.get());
    }
}
