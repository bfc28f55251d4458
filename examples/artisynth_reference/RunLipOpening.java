// Headless run of ArtiSynth's own BadinFaceDemoLipOpening (artisynth_models), for wface's comparison.
//
// Builds the demo exactly as its build() does (the ten OOP rings, BlemkerMuscle at 1e5 Pa, lip-lip and
// lip-skull contact, gravity, ConstrainedBackwardEuler at 5 ms), plays the OOP excitation from an
// ArtiSynth probe data file (the demo's data/approximant/oop.txt: CubicStep, 0.3 at 0.8 s) through a
// NumericInputProbe, as the demo's attach() does, and writes the face's FEM node positions every
// 0.01 s. No viewer: the demo's own area measure counts green pixels on screen, so wface measures the
// aperture from the dumped nodes instead (examples/artisynth_lip_area.py).
//
// Usage (classpath: artisynth_core's classes and jars, artisynth_models' classes; java.library.path:
// the core's native libraries, PardisoJNI, TetgenJNI and RobustPreds):
//   javac -cp $CP RunLipOpening.java
//   java -Djava.awt.headless=true -Djava.library.path=$NATIVE -cp .:$CP RunLipOpening NODES.txt 1.0 OOP.txt
// Options (system properties):
//   -Dlip.contact=all|lips|skull|none   collisions as the demo sets them (all), lip-lip only,
//                                 face-bone only, or none
//   -Dlip.pentol=METRES           MechModel penetration tolerance (default: ArtiSynth's)
//   -Dlip.gravity=false           no gravity
//   -Dlip.tets=true               replace every hex with linear tets before the run, by ArtiSynth's own hex
//                                 split (AnsysReader's TETRAHEDRALIZE_HEXES: HexElement.setParities, then
//                                 Tetrahedralizer.subdivideHex); each muscle element descriptor becomes one per
//                                 tet with its hex's fibre direction; the wedges stay wedges
//   -Dlip.mesh=FILE               run on another tet mesh of the same face (export_wface_tets.py writes wface's):
//                                 the node file's nodes keep their order (moved to the file's rest positions),
//                                 the file's further nodes are added (free; a midpoint whose two end nodes are
//                                 held by a bone is held too), every element is replaced by the file's tets,
//                                 each tet takes the muscle descriptors (direction included) of the ArtiSynth
//                                 element that holds its centroid, and the lip collision surfaces are embedded
//                                 again
//   -Dlip.bilateral=false         lip-lip vertex contacts as unilateral constraints (ArtiSynth's default, true:
//                                 bilateral constraints, dropped once they separate, so a contact can pull for a step)
//   -Dlip.compliance=M_PER_N      lip-lip contact compliance (ArtiSynth's default 0: rigid constraints) and
//   -Dlip.damping=NS_PER_M        its damping
//   -Dlip.softincomp=ELEMENT|NODAL|FULL  how the flesh's bulk term is integrated (the demo leaves ArtiSynth's
//                                 AUTO: ELEMENT, one mean dilatation per element, on the hexes)
//   -Dlip.bulk=QUADRATIC|LOGARITHMIC  the flesh's bulk potential: kappa/2 (J - 1)^2 (the demo's, ArtiSynth's default)
//                                 or kappa/2 (ln J)^2 (wface's default)
//   -Dlip.step=SECONDS            the integrator's step (the demo's: 0.005)
//   -Dlip.directions=FILE         also write each bundle's fibres at rest, a line each: "fibre bundle x0 y0 z0 x1 y1 z1"
//                                 (the two points, where ArtiSynth attached them), then "restfibre bundle x0 y0 z0 x1 y1
//                                 z1" (their rest positions, which computeElementDirections reads), and each muscle
//                                 element's fibre direction and the rest position of the point it was computed at (the
//                                 element's warping point), a line each: "bundle element_number ux uy uz cx cy cz" (as
//                                 computeElementDirections left it); Badin frame, metres
//   -Dlip.redirect=positions      compute every bundle's element directions again from its fibre points' current
//                                 positions instead of their rest positions (equal to within 2e-13 m at the start):
//                                 where fibre midpoints are cospherical that rounding picks other Delaunay tets
//   -Dlip.fixed=FILE              also write the nodes the bones hold, a line each: "node_index fixed|attached"
//                                 (not dynamic, as attachFaceToSkull leaves the cranium's; attached, the jaw's)
//   -Dlip.contacts=FILE           also write the contacts at every dump: per frame a line "T <time s> <count>",
//                                 then per contact "x0 y0 z0 x1 y1 z1 nx ny nz force_N pair" (the two contact
//                                 points, the normal and the force, Badin frame; pair: lips, jaw or maxilla)
// Output: per frame a line "T <time s> <OOP excitation>" and then one line "x y z" (metres, Badin frame)
// per node of the node file, in its order (nodes added by -Dlip.mesh are left out).
import java.io.BufferedWriter;
import java.io.FileWriter;
import java.io.PrintWriter;

import artisynth.core.femmodels.FemElement3d;
import artisynth.core.femmodels.FemModel3d;
import artisynth.core.femmodels.FemMuscleModel;
import artisynth.core.femmodels.FemNode3d;
import artisynth.core.femmodels.HexElement;
import artisynth.core.femmodels.MuscleBundle;
import artisynth.core.femmodels.MuscleElementDesc;
import artisynth.core.femmodels.TetElement;
import artisynth.core.femmodels.Tetrahedralizer;
import artisynth.core.mechmodels.CollisionBehavior;
import artisynth.core.mechmodels.CollisionResponse;
import artisynth.core.mechmodels.ContactData;
import artisynth.core.mechmodels.MechModel;
import artisynth.core.mechmodels.RigidBody;
import artisynth.core.probes.NumericInputProbe;
import artisynth.core.util.TimeBase;
import artisynth.models.face.BadinFaceDemoLipOpening;

public class RunLipOpening {
   static final double DUMP_INTERVAL_S = 0.01;
   static int dumpNodes; // the node file's nodes: the dump leaves out nodes added by -Dlip.mesh

   /**
    * Every bundle's element directions computed again as computeElementDirections does, but from the fibre
    * points' current positions, which at the start equal their rest positions to within 2e-13 m (the two are
    * computed by different arithmetic). Prints, per bundle, how many elements then turn more than 5 degrees.
    */
   private static void redirectFromPositions (FemMuscleModel face) {
      for (MuscleBundle b : face.getMuscleBundles ()) {
         int nf = b.getFibres ().size ();
         if (nf == 0 || b.getElements ().size () == 0) {
            continue;
         }
         maspack.matrix.Point3d[] mids = new maspack.matrix.Point3d[nf];
         maspack.matrix.Vector3d[] dirs = new maspack.matrix.Vector3d[nf];
         for (int i = 0; i < nf; i++) {
            artisynth.core.mechmodels.Muscle f = b.getFibres ().get (i);
            maspack.matrix.Point3d p0 = f.getFirstPoint ().getPosition ();
            maspack.matrix.Point3d p1 = f.getSecondPoint ().getPosition ();
            mids[i] = new maspack.matrix.Point3d ();
            mids[i].add (p1, p0); // as MuscleBundle.getFibreRestDistanceInterpolator
            mids[i].scale (1 / 2.0);
            dirs[i] = new maspack.matrix.Vector3d ();
            dirs[i].sub (p1, p0);
            dirs[i].normalize ();
         }
         maspack.geometry.DelaunayInterpolator interp = new maspack.geometry.DelaunayInterpolator ();
         interp.setPoints (mids);
         int turned = 0;
         for (MuscleElementDesc d : b.getElements ()) {
            maspack.matrix.Vector3d before = new maspack.matrix.Vector3d (d.getDirection ());
            d.interpolateDirection (interp, dirs);
            maspack.matrix.Vector3d after = d.getDirection ();
            double c = Math.abs (before.dot (after)) / (before.norm () * after.norm ());
            if (c < Math.cos (Math.toRadians (5))) {
               turned++;
            }
         }
         System.out.println ("redirect " + b.getName () + ": " + turned + " of " + b.getElements ().size ()
            + " elements turned more than 5 degrees");
      }
   }

   /** A fibre point's rest position as MuscleBundle.getRestPosition reads it. */
   private static maspack.matrix.Point3d restPosition (artisynth.core.mechmodels.Point p) {
      maspack.matrix.Point3d r = new maspack.matrix.Point3d ();
      if (p instanceof FemNode3d) {
         r.set (((FemNode3d)p).getRestPosition ());
      }
      else {
         ((artisynth.core.femmodels.FemMarker)p).getRestPosition (r);
      }
      return r;
   }

   public static void main (String[] args) throws Exception {
      if (args.length != 3) {
         System.err.println ("usage: RunLipOpening NODES_OUT.txt END_TIME_S OOP_PROBE.txt|- [-Dlip.probes=FILE=BUNDLE,...]");
         System.exit (2);
      }
      double tEnd = Double.parseDouble (args[1]);
      BadinFaceDemoLipOpening demo = new BadinFaceDemoLipOpening ();
      demo.build (new String[0]);
      MechModel mech = (MechModel)demo.models ().get ("mech");
      FemMuscleModel face = (FemMuscleModel)mech.models ().get ("badinface");
      MuscleBundle oop = face.getMuscleBundles ().get ("OOP");
      RigidBody jaw = mech.rigidBodies ().get ("badinjaw");
      RigidBody maxilla = mech.rigidBodies ().get ("badinmaxilla");

      dumpNodes = face.numNodes ();
      if (Boolean.parseBoolean (System.getProperty ("lip.tets", "false"))) {
         tetrahedralize (face);
      }
      if (System.getProperty ("lip.mesh") != null) {
         replaceMesh (mech, face, System.getProperty ("lip.mesh"));
      }
      String contact = System.getProperty ("lip.contact", "all");
      if (!java.util.Arrays.asList ("all", "lips", "skull", "none").contains (contact)) {
         throw new IllegalArgumentException ("lip.contact must be all, lips, skull or none, got " + contact);
      }
      if (contact.equals ("lips") || contact.equals ("none")) {
         mech.setCollisionBehavior (face, jaw, false);
         mech.setCollisionBehavior (face, maxilla, false);
      }
      if (contact.equals ("skull") || contact.equals ("none")) {
         mech.setCollisionBehavior (face, face, false);
      }
      if (System.getProperty ("lip.softincomp") != null) {
         face.setSoftIncompMethod (artisynth.core.femmodels.FemModel.IncompMethod.valueOf (System.getProperty ("lip.softincomp")));
      }
      if (System.getProperty ("lip.bulk") != null) { // the flesh's bulk potential: QUADRATIC (the demo's) or LOGARITHMIC
         artisynth.core.materials.IncompressibleMaterialBase flesh =
            (artisynth.core.materials.IncompressibleMaterialBase)face.getMaterial ().clone ();
         flesh.setBulkPotential (
            artisynth.core.materials.IncompressibleMaterialBase.BulkPotential.valueOf (System.getProperty ("lip.bulk")));
         face.setMaterial (flesh);
      }
      if (System.getProperty ("lip.step") != null) {
         mech.setMaxStepSize (Double.parseDouble (System.getProperty ("lip.step")));
      }
      String penTol = System.getProperty ("lip.pentol");
      if (penTol != null) {
         mech.setPenetrationTol (Double.parseDouble (penTol));
      }
      if (!Boolean.parseBoolean (System.getProperty ("lip.gravity", "true"))) {
         mech.setGravity (0, 0, 0);
      }
      CollisionBehavior lips = mech.getCollisionBehavior (face, face);
      if (lips != null && System.getProperty ("lip.bilateral") != null) {
         lips.setBilateralVertexContact (Boolean.parseBoolean (System.getProperty ("lip.bilateral")));
      }
      if (lips != null && System.getProperty ("lip.compliance") != null) {
         lips.setCompliance (Double.parseDouble (System.getProperty ("lip.compliance")));
         lips.setDamping (Double.parseDouble (System.getProperty ("lip.damping", "0")));
      }
      System.out.println (
         "nodes " + face.numNodes () + ", elements " + face.numElements () + ", OOP elements "
         + oop.getElements ().size () + ", step " + mech.getMaxStepSize () + " s, " + mech.getIntegrator ()
         + ", soft incompressibility " + face.getSoftIncompMethod () + ", bulk potential "
         + ((artisynth.core.materials.IncompressibleMaterialBase)face.getMaterial ()).getBulkPotential () + ", gravity " + mech.getGravity () + ", contact " + contact + ", penetration tol "
         + mech.getPenetrationTol () + " m"
         + (lips == null ? "" : ", lip contact friction " + lips.getFriction () + " collider " + lips.getColliderType ()
            + " compliance " + lips.getCompliance () + " bilateral " + lips.getBilateralVertexContact ()
            + " m/N damping " + lips.getDamping () + " N s/m"));

      String contactsFile = System.getProperty ("lip.contacts");
      java.util.LinkedHashMap<String, CollisionResponse> responses = new java.util.LinkedHashMap<> ();
      if (contactsFile != null) {
         responses.put ("lips", mech.setCollisionResponse (face, face));
         responses.put ("jaw", mech.setCollisionResponse (face, jaw));
         responses.put ("maxilla", mech.setCollisionResponse (face, maxilla));
      }
      PrintWriter contacts = contactsFile == null ? null : new PrintWriter (new BufferedWriter (new FileWriter (contactsFile)));
      if (!args[2].equals ("-")) { // "-": OOP is not driven (a gesture's other probes, lip.probes, are)
         demo.addInputProbe (new NumericInputProbe (oop, "excitation", args[2]));
      }
      // -Dlip.probes=FILE=BUNDLE,FILE=exciters/NAME,...: more excitation curves, as a gesture's 0probes.art has them
      String probes = System.getProperty ("lip.probes");
      for (String spec : probes == null ? new String[0] : probes.split (",")) {
         String[] kv = spec.split ("=");
         artisynth.core.modelbase.ModelComponent target = kv[1].startsWith ("exciters/")
            ? face.getMuscleExciters ().get (kv[1].substring ("exciters/".length ()))
            : face.getMuscleBundles ().get (kv[1]);
         if (target == null) {
            throw new IllegalArgumentException ("lip.probes: the face has no muscle bundle or exciter " + kv[1]);
         }
         demo.addInputProbe (new NumericInputProbe (target, "excitation", kv[0]));
         System.out.println ("probe " + kv[0] + " drives " + kv[1]);
      }
      if ("positions".equals (System.getProperty ("lip.redirect"))) {
         redirectFromPositions (face);
      }
      String muscleFile = System.getProperty ("lip.muscles"); // each bundle's and exciter's elements, by number
      if (muscleFile != null) {
         try (PrintWriter mf = new PrintWriter (new BufferedWriter (new FileWriter (muscleFile)))) {
            for (MuscleBundle b : face.getMuscleBundles ()) {
               mf.print ("bundle " + b.getName ());
               for (artisynth.core.femmodels.MuscleElementDesc d : b.getElements ()) {
                  mf.print (" " + d.getElement ().getNumber ());
               }
               mf.println ();
            }
            for (artisynth.core.mechmodels.MuscleExciter x : face.getMuscleExciters ()) {
               mf.print ("exciter " + x.getName ());
               for (int k = 0; k < x.numTargets (); k++) {
                  if (x.getTarget (k) instanceof artisynth.core.femmodels.MuscleElementDesc) {
                     mf.print (" " + ((artisynth.core.femmodels.MuscleElementDesc)x.getTarget (k)).getElement ().getNumber ());
                  }
               }
               mf.println ();
            }
         }
      }
      String dirFile = System.getProperty ("lip.directions"); // each bundle element's rest fibre direction
      if (dirFile != null) {
         try (PrintWriter df = new PrintWriter (new BufferedWriter (new FileWriter (dirFile)))) {
            for (MuscleBundle b : face.getMuscleBundles ()) {
               for (artisynth.core.mechmodels.Muscle f : b.getFibres ()) {
                  maspack.matrix.Point3d p0 = f.getFirstPoint ().getPosition ();
                  maspack.matrix.Point3d p1 = f.getSecondPoint ().getPosition ();
                  df.println ("fibre " + b.getName () + " " + p0.x + " " + p0.y + " " + p0.z + " " + p1.x + " " + p1.y
                     + " " + p1.z);
                  maspack.matrix.Point3d r0 = restPosition (f.getFirstPoint ());
                  maspack.matrix.Point3d r1 = restPosition (f.getSecondPoint ());
                  df.println ("restfibre " + b.getName () + " " + r0.x + " " + r0.y + " " + r0.z + " " + r1.x + " "
                     + r1.y + " " + r1.z);
               }
               for (artisynth.core.femmodels.MuscleElementDesc d : b.getElements ()) {
                  maspack.matrix.Vector3d u = d.getDirection ();
                  maspack.matrix.Point3d c = new maspack.matrix.Point3d ();
                  d.getElement ().getWarpingPoint ().computeRestPosition (c, d.getElement ().getNodes ());
                  df.println (b.getName () + " " + d.getElement ().getNumber () + " " + u.x + " " + u.y + " " + u.z + " "
                     + c.x + " " + c.y + " " + c.z);
               }
            }
         }
      }
      String fixedFile = System.getProperty ("lip.fixed"); // the nodes the bones hold
      if (fixedFile != null) {
         try (PrintWriter ff = new PrintWriter (new BufferedWriter (new FileWriter (fixedFile)))) {
            for (int i = 0; i < face.numNodes (); i++) {
               FemNode3d n = face.getNode (i);
               if (!n.isDynamic () || n.isAttached ()) {
                  ff.println (i + " " + (n.isAttached () ? "attached" : "fixed"));
               }
            }
         }
      }
      demo.initialize (0);
      double h = mech.getMaxStepSize ();
      int steps = (int)Math.round (tEnd / h);
      int every = (int)Math.round (DUMP_INTERVAL_S / h);
      long start = System.nanoTime ();
      try (PrintWriter out = new PrintWriter (new BufferedWriter (new FileWriter (args[0])))) {
         dump (out, 0, oop, face);
         for (int k = 0; k < steps; k++) {
            // times on ArtiSynth's time base: unrounded k*h can stall RootModel.advance
            double ta = TimeBase.round (k * h), tb = TimeBase.round ((k + 1) * h);
            demo.advance (ta, tb, 0);
            if ((k + 1) % every == 0) {
               dump (out, tb, oop, face);
               out.flush ();
               if (contacts != null) {
                  dumpContacts (contacts, tb, responses);
               }
               System.out.printf (
                  "t=%.3f s OOP=%.4f wall %.1f s%n", tb, oop.getExcitation (), (System.nanoTime () - start) * 1e-9);
            }
         }
      }
      if (contacts != null) {
         contacts.close ();
      }
   }

   /** Replaces every hex of the face by the tets of ArtiSynth's own split; the muscles keep their directions. */
   static void tetrahedralize (FemMuscleModel face) {
      java.util.ArrayList<HexElement> hexes = new java.util.ArrayList<> ();
      for (FemElement3d e : face.getElements ()) {
         if (e instanceof HexElement) {
            hexes.add ((HexElement)e);
         }
      }

      HexElement.setParities (hexes);
      Tetrahedralizer tetrahedralizer = new Tetrahedralizer ();
      java.util.HashMap<FemElement3d, java.util.List<TetElement>> split = new java.util.HashMap<> ();
      int dropped = 0;
      double droppedVolume = 0, keptVolume = 0;
      for (HexElement hex : hexes) {
         FemNode3d[] n = hex.getNodes ();
         java.util.ArrayList<TetElement> kept = new java.util.ArrayList<> ();
         for (TetElement tet : tetrahedralizer.subdivideHex (n[0], n[1], n[2], n[3], n[4], n[5], n[6], n[7], hex.getParity () != 1)) {
            FemNode3d[] q = tet.getNodes ();
            double v = TetElement.computeVolume (q[0], q[1], q[2], q[3]);
            if (v <= 0) { // the split of a twisted hex: the hex's other tets keep its volume's bulk
               droppedVolume += v;
               dropped++;
               continue;
            }
            face.addElement (tet);
            kept.add (tet);
            keptVolume += v;
         }
         split.put (hex, kept);
      }
      int descriptors = moveMuscles (face, split);
      for (HexElement hex : hexes) {
         face.removeElement (hex);
      }
      reembedLips (face);
      System.out.println (
         "tets: " + hexes.size () + " hexes -> " + face.numElements () + " elements, " + descriptors
         + " muscle descriptors; " + dropped + " tets inverted at rest left out (" + droppedVolume + " m^3), the tets' volume " + keptVolume + " m^3");
   }

   /** Replaces the face's elements by the tets in FILE (see -Dlip.mesh); the muscles keep their directions. */
   static void replaceMesh (MechModel mech, FemMuscleModel face, String file) throws java.io.IOException {
      java.util.List<String> lines = java.nio.file.Files.readAllLines (java.nio.file.Paths.get (file));
      String[] head = lines.get (0).trim ().split ("\\s+");
      int nNodes = Integer.parseInt (head[1]), nFile = Integer.parseInt (head[2]);
      if (!head[0].equals ("NODES") || nFile != face.numNodes ()) {
         throw new IllegalArgumentException (file + ": expected 'NODES <count> " + face.numNodes () + "', got " + lines.get (0));
      }
      maspack.matrix.Point3d[] x = new maspack.matrix.Point3d[nNodes];
      int[][] ends = new int[nNodes][]; // a midpoint node's two end nodes, which it follows onto a bone
      for (int i = 0; i < nNodes; i++) {
         String[] w = lines.get (1 + i).trim ().split ("\\s+");
         x[i] = new maspack.matrix.Point3d (Double.parseDouble (w[0]), Double.parseDouble (w[1]), Double.parseDouble (w[2]));
         if (w.length == 5) {
            ends[i] = new int[] {Integer.parseInt (w[3]), Integer.parseInt (w[4])};
         }
      }
      String[] th = lines.get (1 + nNodes).trim ().split ("\\s+");
      int nTets = Integer.parseInt (th[1]);
      int[][] tets = new int[nTets][4];
      for (int k = 0; k < nTets; k++) {
         String[] w = lines.get (2 + nNodes + k).trim ().split ("\\s+");
         for (int j = 0; j < 4; j++) {
            tets[k][j] = Integer.parseInt (w[j]);
         }
      }
      // the ArtiSynth element holding each tet's centroid, found before anything moves
      java.util.ArrayList<FemElement3d> old = new java.util.ArrayList<> ();
      for (FemElement3d e : face.getElements ()) {
         old.add (e);
      }
      FemElement3d[] host = new FemElement3d[nTets];
      int outside = 0;
      for (int k = 0; k < nTets; k++) {
         maspack.matrix.Point3d c = new maspack.matrix.Point3d ();
         for (int j = 0; j < 4; j++) {
            c.scaledAdd (0.25, x[tets[k][j]]);
         }
         host[k] = face.findContainingElement (c);
         if (host[k] == null) {
            host[k] = (FemElement3d)face.findNearestElement (new maspack.matrix.Point3d (), c);
            outside++;
         }
      }
      int moved = 0, fixed = 0, attached = 0;
      FemNode3d[] nodes = new FemNode3d[nNodes];
      for (int i = 0; i < nNodes; i++) {
         if (i < nFile) {
            nodes[i] = face.getNodes ().get (i);
            if (nodes[i].getRestPosition ().distance (x[i]) > 1e-9) {
               nodes[i].setRestPosition (x[i]);
               nodes[i].setPosition (x[i]);
               moved++;
            }
         }
         else {
            nodes[i] = new FemNode3d (x[i]);
            face.addNode (nodes[i]);
            if (ends[i] != null) {
               // held: fixed, or attached to a bone (the demo's bones do not move); a midpoint of two held
               // nodes is held: attached to their bone when they share one, else fixed
               FemNode3d a = nodes[ends[i][0]], b = nodes[ends[i][1]];
               boolean heldA = !a.isDynamic () || a.getAttachment () != null, heldB = !b.isDynamic () || b.getAttachment () != null;
               artisynth.core.mechmodels.Frame fa = bone (a), fb = bone (b);
               if (fa != null && fa == fb) {
                  mech.attachPoint (nodes[i], (RigidBody)fa);
                  attached++;
               }
               else if (heldA && heldB) {
                  nodes[i].setDynamic (false);
                  fixed++;
               }
            }
         }
      }
      java.util.HashMap<FemElement3d, java.util.List<TetElement>> children = new java.util.HashMap<> ();
      for (FemElement3d e : old) {
         children.put (e, new java.util.ArrayList<> ()); // every element goes: its muscles go with it
      }
      for (int k = 0; k < nTets; k++) {
         FemNode3d a = nodes[tets[k][0]], b = nodes[tets[k][1]], c = nodes[tets[k][2]], d = nodes[tets[k][3]];
         TetElement tet = TetElement.computeVolume (a, b, c, d) >= 0 ? new TetElement (a, b, c, d) : new TetElement (a, c, b, d);
         face.addElement (tet);
         children.get (host[k]).add (tet);
      }
      int descriptors = moveMuscles (face, children);
      for (FemElement3d e : old) {
         face.removeElement (e);
      }
      reembedLips (face);
      System.out.println (
         "mesh " + file + ": " + nNodes + " nodes (" + (nNodes - nFile) + " added, " + moved + " moved; of the added, " + fixed + " fixed and " + attached
         + " attached to a bone with their end nodes), " + nTets
         + " tets (" + outside + " centroids outside ArtiSynth's mesh, given the nearest element), " + descriptors
         + " muscle descriptors");
   }

   /**
    * Moves every muscle element descriptor whose element is a key of {@code children} onto those tets, one
    * descriptor per tet with the element's fibre direction; descriptors of other elements stay. An exciter's
    * target moves with it (until 2026-12-07 the exciters kept the removed descriptors, so OOMl drove nothing
    * on tets). Returns the number of descriptors made.
    */
   static int moveMuscles (FemMuscleModel face, java.util.Map<FemElement3d, java.util.List<TetElement>> children) {
      int made = 0;
      java.util.Map<MuscleElementDesc, java.util.List<MuscleElementDesc>> movedTo = new java.util.HashMap<> ();
      for (MuscleBundle bundle : face.getMuscleBundles ()) {
         java.util.ArrayList<MuscleElementDesc> descs = new java.util.ArrayList<> ();
         for (MuscleElementDesc desc : bundle.getElements ()) {
            descs.add (desc);
         }
         for (MuscleElementDesc desc : descs) {
            java.util.List<TetElement> tets = children.get (desc.getElement ());
            if (tets == null) {
               continue;
            }
            maspack.matrix.Vector3d direction = desc.getDirection ();
            if (direction == null) {
               throw new IllegalStateException ("muscle element of " + bundle.getName () + " has no single direction");
            }
            bundle.getElements ().remove (desc);
            java.util.List<MuscleElementDesc> made_here = new java.util.ArrayList<> ();
            for (TetElement tet : tets) {
               MuscleElementDesc d = new MuscleElementDesc ();
               d.setElement (tet);
               d.setDirection (new maspack.matrix.Vector3d (direction));
               bundle.addElement (d);
               made_here.add (d);
               made++;
            }
            movedTo.put (desc, made_here);
         }
      }
      // an exciter that targets a moved descriptor (OOMl: 232 of OOM's) targets its tets' instead, at its gain
      for (artisynth.core.mechmodels.MuscleExciter x : face.getMuscleExciters ()) {
         for (int k = x.numTargets () - 1; k >= 0; k--) {
            java.util.List<MuscleElementDesc> to = movedTo.get (x.getTarget (k));
            if (to != null) {
               double gain = x.getGain (k);
               x.removeTarget (x.getTarget (k));
               for (MuscleElementDesc d : to) {
                  x.addTarget (d, gain);
               }
            }
         }
      }
      return made;
   }

   static artisynth.core.mechmodels.Frame bone (FemNode3d n) {
      if (n.getAttachment () instanceof artisynth.core.mechmodels.PointFrameAttachment) {
         return ((artisynth.core.mechmodels.PointFrameAttachment)n.getAttachment ()).getFrame ();
      }
      return null;
   }

   /** The demo's lip collision surfaces are embedded in the elements: embed them again in the new ones. */
   static void reembedLips (FemMuscleModel face) {
      for (String name : new String[] {"lowerlip", "upperlip"}) {
         artisynth.core.femmodels.FemMeshComp comp = face.getMeshComp (name);
         if (comp != null) {
            maspack.geometry.PolygonalMesh mesh = ((maspack.geometry.PolygonalMesh)comp.getMesh ()).copy ();
            face.removeMeshComp (comp);
            face.addMesh (name, mesh);
         }
      }
   }

   static void dumpContacts (PrintWriter out, double t, java.util.Map<String, CollisionResponse> responses) {
      int count = 0;
      for (CollisionResponse r : responses.values ()) {
         count += r.getContactData ().size ();
      }
      out.printf ("T %.6f %d%n", t, count);
      for (java.util.Map.Entry<String, CollisionResponse> e : responses.entrySet ()) {
         for (ContactData c : e.getValue ().getContactData ()) {
            out.printf (
               "%.9g %.9g %.9g %.9g %.9g %.9g %.6g %.6g %.6g %.6g %s%n", c.getPosition0 ().x, c.getPosition0 ().y,
               c.getPosition0 ().z, c.getPosition1 ().x, c.getPosition1 ().y, c.getPosition1 ().z, c.getNormal ().x,
               c.getNormal ().y, c.getNormal ().z, c.getContactForceScalar (), e.getKey ());
         }
      }
      out.flush ();
   }

   static void dump (PrintWriter out, double t, MuscleBundle oop, FemModel3d face) {
      out.printf ("T %.6f %.6f%n", t, oop.getExcitation ());
      for (int i = 0; i < dumpNodes; i++) {
         FemNode3d n = face.getNodes ().get (i);
         out.printf ("%.9g %.9g %.9g%n", n.getPosition ().x, n.getPosition ().y, n.getPosition ().z);
      }
   }
}
